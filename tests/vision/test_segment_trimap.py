"""GrabCut's trimap drawn from the motion evidence (layercam.vision.segment.moving.sure_background,
edges.grabcut_refine's ``still``): sure background only where the motion measured a pixel static."""

from __future__ import annotations

import numpy as np

from layercam.core import metrics
from layercam.vision import flow, segment


def _halting_clip(T=10, size=64, side=18, still=5, seed=1):
    """A static textured background and a textured square that stands still in frames
    ``0 .. still-1`` and then walks 3 px a frame: ``(frames, masks)``."""
    import cv2

    rng = np.random.default_rng(seed)
    bg = cv2.GaussianBlur(rng.uniform(0, 1, (size, size, 3)).astype(np.float32), (0, 0), 1.5)
    bg = 0.1 + 0.4 * (bg - bg.min()) / (bg.max() - bg.min())
    tex = cv2.GaussianBlur(rng.uniform(0, 1, (side, side, 3)).astype(np.float32), (0, 0), 0.8)
    tex = 0.6 + 0.4 * (tex - tex.min()) / (tex.max() - tex.min())
    frames, masks = [], []
    for t in range(T):
        x0 = 8 + 3 * max(0, t - still + 1)
        f = bg.copy()
        f[20 : 20 + side, x0 : x0 + side] = tex
        mk = np.zeros((size, size), bool)
        mk[20 : 20 + side, x0 : x0 + side] = True
        frames.append(f)
        masks.append(mk)
    return np.stack(frames), np.stack(masks)


def test_a_still_part_of_a_moving_object_is_not_sure_background():
    """The square stands still in frames 0-4, longer than the evidence's reach (2 frames), so no
    pair of frames 0-2 sees it move: the motion measures it static there, yet its track moves
    later, so it must not be sure background; most of the background is."""
    frames, truth = _halting_clip()
    fw, bw = flow.compute_flow(frames, "dis_fast", progress=False)
    fo, bo = flow.flow_consistency(fw, bw), flow.flow_consistency(bw, fw)
    _, info = segment.motion_masks(fw, bw, fo, bo, segment.SegmentConfig(reach=2), frames=frames)
    sure = info["still"]
    assert sure.shape == truth.shape and sure.dtype == bool
    for t in range(3):
        assert sure[t][truth[t]].mean() < 0.2, (t, sure[t][truth[t]].mean())
        assert sure[t][~truth[t]].mean() > 0.5, (t, sure[t][~truth[t]].mean())


def test_along_tracks_carries_a_flag_along_consistent_flow_only():
    """A flag in the last frame reaches the first along a still clip's zero flow, and stops where
    the forward-backward check fails."""
    from layercam.vision.segment.moving import along_tracks

    T, h, w = 4, 16, 16
    flag = np.zeros((T, h, w), bool)
    flag[-1, 4:8, 4:8] = True
    zero = np.zeros((T - 1, h, w, 2), np.float32)
    ok = np.ones((T - 1, h, w), bool)
    out = along_tracks(flag, zero, zero, ok, ok)
    assert out[:, 4:8, 4:8].all() and out.sum() == T * 16
    ok[1] = False  # frame 1's pixels cannot be followed to frame 2
    out = along_tracks(flag, zero, zero, ok, ok)
    assert out[2:, 4:8, 4:8].all() and not out[:2].any()


def test_grabcut_takes_back_what_the_motion_did_not_measure_static():
    """A mask on a third of an object of its own colour: with the whole far field sure background
    (``still`` None) GrabCut cannot reach the rest of the object; where the motion did not measure
    the object static, it takes it back."""
    from layercam.vision.segment.edges import grabcut_refine

    rng = np.random.default_rng(0)
    frame = (0.2 + 0.1 * rng.uniform(0, 1, (80, 80, 3))).astype(np.float32)
    truth = np.zeros((80, 80), bool)
    truth[25:55, 10:70] = True
    frame[truth] = (0.9, 0.5, 0.1)
    part = np.zeros_like(truth)
    part[25:55, 10:30] = True
    band = grabcut_refine(frame, part)
    grown = grabcut_refine(frame, part, still=~truth)
    assert metrics.iou(band, truth) < 0.6 < 0.9 < metrics.iou(grown, truth), (metrics.iou(band, truth), metrics.iou(grown, truth))
