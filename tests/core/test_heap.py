"""The peak resident memory of a part of a run (core.heap)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from layercam.core import heap

pytestmark = pytest.mark.skipif(not Path("/proc/self/clear_refs").exists(), reason="needs Linux's /proc/self/clear_refs")


def test_a_reset_peak_forgets_a_freed_array_and_the_process_peak_keeps_it():
    big = np.ones(300 * 2**20 // 8)  # 300 MiB, touched
    with_big = heap.peak_bytes()
    del big
    heap.reset_peak()
    after = heap.peak_bytes()
    assert with_big - after > 250 * 2**20  # the next part's peak does not count the freed array
    assert heap.process_peak_bytes() >= with_big - 4 * 2**20  # ... and the process's peak still does (the kernel counts lazily)
    heap.reset_peak()  # again, just before: a long-lived worker's resident file pages may have been dropped since
    base = heap.peak_bytes()
    more = np.ones(100 * 2**20 // 8)  # above glibc's largest mmap threshold (32 MiB): fresh pages, not a reused heap
    assert heap.peak_bytes() >= base + 90 * 2**20
    del more


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
