"""The peak resident memory of a part of a run (core.heap)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from layercam.core import heap

pytestmark = pytest.mark.skipif(not Path("/proc/self/clear_refs").exists(),
                                reason="needs Linux's /proc/self/clear_refs")


_PEAK_SCRIPT = """
import json, numpy as np
from layercam.core import heap
MiB = 2**20
big = np.ones(600 * MiB // 8)  # touched
with_big = heap.peak_bytes()
del big
heap.reset_peak()
after = heap.peak_bytes()
process = heap.process_peak_bytes()
heap.reset_peak()
base = heap.peak_bytes()
more = np.ones(400 * MiB // 8)  # above glibc's largest mmap threshold (32 MiB): fresh pages, not a reused heap
print(json.dumps(dict(with_big=with_big, after=after, process=process, base=base, more=heap.peak_bytes())))
"""


def test_a_reset_peak_forgets_a_freed_array_and_the_process_peak_keeps_it():
    """In a fresh process: a long-lived test worker's resident memory (gigabytes, file pages the
    kernel may drop under other jobs' pressure) hid a new array's pages in the worker's own peak.
    The margins leave room for the kernel's lazy per-thread counting (up to 63 faults of 2 MiB)."""
    import json
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _PEAK_SCRIPT], capture_output=True, text=True, check=True)
    m = json.loads(out.stdout.strip().splitlines()[-1])
    MiB = 2**20
    assert m["with_big"] - m["after"] > 400 * MiB  # the next part's peak does not count the freed array
    assert m["process"] >= m["with_big"] - 4 * MiB  # ... and the process's peak still does
    assert m["more"] >= m["base"] + 250 * MiB  # a new array after a reset raises the peak


def test_giving_back_frees_a_cycle_that_holds_an_array():
    """What a finished window leaves in reference cycles (its model and results refer to each other)
    is freed when the window ends, not at the cyclic collector's next full pass."""
    import gc

    def rss() -> int:
        return heap.proc_status()["VmRSS"] * 1024

    gc.disable()  # as between the collector's rare full passes
    try:
        a, b = {"arr": np.ones(200 * 2**20 // 8)}, {}
        a["other"], b["other"] = b, a  # a cycle
        del a, b
        held = rss()
        heap.give_back_freed_memory()
        assert held - rss() > 150 * 2**20
    finally:
        gc.enable()
