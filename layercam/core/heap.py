"""The C heap between the parts of a long run."""

from __future__ import annotations


def give_back_freed_memory() -> None:
    """Returns the C heap's free pages to the system (glibc ``malloc_trim``; nothing elsewhere). A
    window's arrays are freed when it ends, but the allocator keeps the heap it grew for them
    (fragmented by the small arrays still alive), so that without this the memory held between
    windows is what the last windows freed as well as what the run needs."""
    import ctypes

    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc
        pass
