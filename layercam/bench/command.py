"""``layercam`` run from a benchmark as a user runs it: ``python -m layercam ARGV`` in a process of
its own (the benchmarks sit below the command line: they start it, never import it), its wall
time and that process's own peak memory (``wait4``'s ``ru_maxrss``)."""

from __future__ import annotations

import os
import subprocess
import sys
import time


def run_layercam(argv: list[str], threads: int | None = None) -> dict:
    """``layercam ARGV`` in a child process (its output goes where this process's goes; torch's
    threads from ``OMP_NUM_THREADS``: ``threads`` when given). Returns ``{"returncode", "wall_s",
    "peak_mem_mb"}`` (MiB)."""
    env = dict(os.environ, **({"OMP_NUM_THREADS": str(threads)} if threads else {}))
    t0 = time.perf_counter()
    p = subprocess.Popen([sys.executable, "-m", "layercam", *argv], env=env)
    _, status, usage = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    p.returncode = os.waitstatus_to_exitcode(status)  # reaped here: Popen must not wait for it again
    return {"returncode": p.returncode, "wall_s": wall, "peak_mem_mb": round(usage.ru_maxrss / 1024.0, 1)}
