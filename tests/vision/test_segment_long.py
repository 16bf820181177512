"""A long clip's motion segmentation in windows (layercam.vision.segment.long): each window read at
the finder's working size a frame or a pair at a time gives what the finder makes of the whole
window, and a clip of one window gets the masks and mapping of the whole-clip bootstrap."""

from __future__ import annotations

import numpy as np

from layercam.core.config import SegmentConfig
from layercam.vision import flow, segment
from layercam.vision.segment.long import foreground_bootstrap_long, window_at_work


def _flows(frames):
    fw, bw = flow.compute_flow(frames, "dis_fast", progress=False)
    return {"fw": fw, "bw": bw, "fw_ok": flow.flow_consistency(fw, bw),
            "bw_ok": flow.flow_consistency(bw, fw), "homs": flow.global_homographies(fw)}


def test_a_window_read_at_the_working_size_is_the_finders_own_resize(monkeypatch):
    """Frames at twice the flow's grid, the grid above the finder's working size: the window read a
    frame (pair) at a time equals ``segment._working`` of the window read whole at the grid."""
    import cv2

    monkeypatch.setattr(segment, "WORK_SHORT", 12)
    rng = np.random.default_rng(0)
    frames = rng.random((7, 60, 88, 3), dtype=np.float32)
    fl = {"fw": rng.normal(0, 3, (6, 30, 44, 2)).astype(np.float16),
          "bw": rng.normal(0, 3, (6, 30, 44, 2)).astype(np.float16),
          "fw_ok": rng.random((6, 30, 44)) > 0.3, "bw_ok": rng.random((6, 30, 44)) > 0.3}
    fr, got = window_at_work(frames, fl, 2, 6, (30, 44))
    grid = np.stack([cv2.resize(f, (44, 30), interpolation=cv2.INTER_AREA) for f in frames[2:6]])
    ref_fr, ref = segment._working(grid, {k: v[2:5] for k, v in fl.items()})
    assert fr.shape == (4, 12, 18, 3) and np.array_equal(fr, ref_fr)
    assert set(got) == set(ref) and all(got[k].dtype == ref[k].dtype and np.array_equal(got[k], ref[k]) for k in ref)


def test_a_clip_of_one_window_gets_the_whole_clip_bootstrap(tmp_path, monkeypatch):
    """At a working size below the frames' (the finder scales them down), the windowed bootstrap of
    a clip that fits in one window writes the masks, and returns the mapping, of
    :func:`segment.foreground_bootstrap` on the whole clip."""
    from test_segment import _square_clip

    monkeypatch.setattr(segment, "WORK_SHORT", 32)
    frames = _square_clip(T=8)[0]
    fl = _flows(frames)
    whole = segment.foreground_bootstrap(frames, fl)
    long = foreground_bootstrap_long(frames, fl, tmp_path, None, SegmentConfig())
    assert long["computed"] and long["info"]["windows"] == 1 and (tmp_path / "masks.raw").exists()
    assert np.array_equal(np.asarray(long["masks"]) > 0, whole["masks"] > 0.5) and whole["masks"].any()
    assert np.array_equal(long["h0"], whole["h0"]) and long["how"] == whole["how"]
