"""The C heap between the parts of a long run, and the peak resident memory of each part."""

from __future__ import annotations


def give_back_freed_memory() -> None:
    """Frees what a finished part of the run (a window) left in reference cycles, then returns the C
    heap's free pages to the system (glibc ``malloc_trim``; nothing elsewhere). A window's model,
    optimiser and stage results refer to each other, so they are freed by Python's cyclic collector,
    whose full passes are rare: without one, each window's arrays outlived it and the memory held
    grew by a window's working set each window. And the allocator keeps the heap it grew for them
    (fragmented by the small arrays still alive): without the trim the memory held between windows
    is what the last windows freed as well as what the run needs."""
    import ctypes
    import gc

    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc
        pass


_PEAK = [0]  # the largest high-water mark read before a reset (bytes)


def proc_status(pid: int | str = "self") -> dict:
    """The memory lines of ``/proc/PID/status`` (``VmRSS``, ``VmHWM``, ``RssAnon``, ``RssFile``,
    ``RssShmem``) in kB; empty where there is no such file (not Linux, or the process is gone)."""
    out = {}
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                k, _, v = line.partition(":")
                if k in ("VmRSS", "VmHWM", "RssAnon", "RssFile", "RssShmem"):
                    out[k] = int(v.split()[0])
    except (OSError, ValueError, IndexError):
        pass
    return out


def peak_bytes() -> int | None:
    """This process's peak resident memory since :func:`reset_peak` (the kernel's ``VmHWM``; bytes),
    None where the kernel does not say (not Linux)."""
    kb = proc_status().get("VmHWM")
    return None if kb is None else kb * 1024


def reset_peak() -> None:
    """Starts a new high-water mark (``/proc/self/clear_refs``, 5): :func:`peak_bytes` then says the
    peak of what follows, e.g. one stage's. The mark so far is kept for :func:`process_peak_bytes`."""
    now = peak_bytes()
    if now is None:
        return
    _PEAK[0] = max(_PEAK[0], now)
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        pass


def process_peak_bytes() -> int | None:
    """This process's peak resident memory since it started, across :func:`reset_peak` (bytes; the
    resource module's ``ru_maxrss`` where ``/proc`` is absent), None where unknown."""
    now = peak_bytes()
    if now is not None:
        return max(_PEAK[0], now)
    try:
        import resource

        return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024
    except (ImportError, OSError):
        return None
