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
    small = np.ones(20 * 2**20 // 8)
    assert heap.peak_bytes() >= after + 15 * 2**20
    del small
