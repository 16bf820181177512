"""``layercam`` run from a benchmark as a user runs it: ``python -m layercam ARGV`` in a process of
its own (the benchmarks sit below the command line: they start it, never import it), its wall
time and its peak memory."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path


def run_layercam(argv: list[str], threads: int | None = None, report: Path | None = None) -> dict:
    """``layercam ARGV`` in a child process (its output goes where this process's goes; torch's
    threads from ``OMP_NUM_THREADS``: ``threads`` when given). Returns ``{"returncode", "wall_s",
    "peak_mem_mb"}`` (MiB): the peak the run's ``report`` (its ``report.json``) says it held, the
    kernel's high-water mark up to the report (not the pages the interpreter touches as it exits),
    else the process's own (``wait4``'s ``ru_maxrss``)."""
    env = dict(os.environ, **({"OMP_NUM_THREADS": str(threads)} if threads else {}))
    t0 = time.perf_counter()
    p = subprocess.Popen([sys.executable, "-m", "layercam", *argv], env=env)
    _, status, usage = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    p.returncode = os.waitstatus_to_exitcode(status)  # reaped here: Popen must not wait for it again
    peak = usage.ru_maxrss / 1024.0
    if report is not None and p.returncode == 0 and Path(report).is_file():
        peak = (json.loads(Path(report).read_text()).get("memory", {}).get("peak_rss_bytes") or peak * 2**20) / 2**20
    return {"returncode": p.returncode, "wall_s": wall, "peak_mem_mb": round(peak, 1)}
