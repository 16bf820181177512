"""The finder's edge steps (:mod:`layercam.vision.segment.edges`): GrabCut and the guided filter."""

import numpy as np

from layercam.core import metrics
from layercam.vision.segment.edges import grabcut_refine, guided_matte, guided_refine


def _square(size: int = 80):
    rng = np.random.default_rng(0)
    frame = (0.2 + 0.1 * rng.uniform(0, 1, (size, size, 3))).astype(np.float32)
    truth = np.zeros((size, size), bool)
    truth[25:55, 20:50] = True
    frame[truth] = (0.9, 0.5, 0.1)
    return frame, truth


def test_grabcut_pulls_an_overshooting_mask_to_the_objects_edge():
    """Step 4's contract: a mask 4 px too large on every side of a square of its own colour is
    pulled back to the square; a mask too small to seed GrabCut comes back as it was."""
    frame, truth = _square()
    over = np.zeros_like(truth)
    over[21:59, 16:54] = True
    out = grabcut_refine(frame, over)
    assert out.shape == truth.shape and out.dtype == bool
    assert metrics.iou(out, truth) > 0.9 > metrics.iou(over, truth)
    tiny = np.zeros_like(truth)
    tiny[5:7, 5:7] = True
    assert (grabcut_refine(frame, tiny) == tiny).all()


def test_the_guided_filter_moves_a_masks_edge_to_the_colour_edge_within_its_window():
    """Step 6's guided filter: a mask a pixel too large, or a pixel too small, on every side of a square
    of its own colour comes back at the square; on a frame without edges a mask keeps its place."""
    frame, truth = _square()
    for off in (1, -1):
        m = np.zeros_like(truth)
        m[25 - off:55 + off, 20 - off:50 + off] = True
        out = guided_refine(frame, m)
        assert out.shape == truth.shape and out.dtype == bool
        assert metrics.iou(out, truth) > 0.97 > metrics.iou(m, truth) + 0.05, off
    flat = np.full_like(frame, 0.4)
    assert metrics.iou(guided_refine(flat, truth), truth) > 0.97


def test_the_guided_matte_is_in_zero_one_and_its_half_level_is_the_refined_mask():
    """What the exports write as the foreground's matte: the guided filter's output, clipped to [0, 1],
    whose level one half is :func:`guided_refine`'s mask."""
    frame, truth = _square()
    m = np.zeros_like(truth)
    m[24:56, 19:51] = True
    q = guided_matte(frame, m)
    assert q.dtype == np.float32 and q.shape == truth.shape and 0.0 <= q.min() and q.max() <= 1.0
    assert np.array_equal(q > 0.5, guided_refine(frame, m))
    assert metrics.iou(q > 0.5, truth) > 0.97
