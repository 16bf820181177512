"""The finder's motion contrast: what clings to the object but hardly moves against the camera leaves."""

from __future__ import annotations

import numpy as np

from layercam.vision.segment.contrast import camera_departure, contrast_refine, moving_part


def _clip(T=6, h=64, w=96):
    """A camera pan (homography t -> t+1 a shift), an object moving 4 px a frame against it and a
    swaying crowd beside it moving 0.3 px a frame; the mask holds both."""
    pan = np.array([-1.0, -0.5], np.float32)
    homs = np.stack([np.array([[1, 0, pan[0]], [0, 1, pan[1]], [0, 0, 1]])] * (T - 1))
    obj = np.zeros((h, w), bool)
    obj[16:48, 30:54] = True
    crowd = np.zeros((h, w), bool)
    crowd[20:44, 54:66] = True  # touches the object's right edge
    fw = np.broadcast_to(pan, (T - 1, h, w, 2)).copy()
    bw = -fw
    fw[:, obj] += [4.0, 0.0]
    bw[:, obj] -= [4.0, 0.0]
    fw[:, crowd] += [0.0, 0.3]
    bw[:, crowd] -= [0.0, 0.3]
    return fw, bw, homs, obj, crowd


def test_camera_departure_are_the_departure_from_the_pan():
    fw, bw, homs, obj, crowd = _clip()
    res = camera_departure(fw, bw, homs)
    assert res.shape == (6, 64, 96)
    bg = ~obj & ~crowd
    assert np.abs(res[:, bg]).max() < 1e-4
    np.testing.assert_allclose(res[:, obj], 4.0, atol=1e-4)
    np.testing.assert_allclose(res[:, crowd], 0.3, atol=1e-4)


def test_contrast_refine_drops_the_still_crowd_and_keeps_the_object():
    fw, bw, homs, obj, crowd = _clip()
    masks = np.broadcast_to(obj | crowd, (6,) + obj.shape).copy()
    masks[3] = False  # an empty frame stays empty
    out = contrast_refine(masks, fw, bw, homs)
    for t in (0, 1, 2, 4, 5):
        assert out[t][obj].mean() > 0.97 and out[t][crowd].mean() < 0.05
    assert not out[3].any()


def test_contrast_refine_keeps_a_mask_that_moves_as_one():
    """An object moving at one speed has no part under the contrast: nothing leaves."""
    fw, bw, homs, obj, crowd = _clip()
    masks = np.broadcast_to(obj, (6,) + obj.shape).copy()
    out = contrast_refine(masks, fw, bw, homs)
    assert (out == masks).all()


def test_the_level_is_the_object_s_own_where_the_mask_took_in_more_crowd_than_object():
    """A mask that is 40% still ground, 25% swaying crowd (0.5 px) and 35% object (4 px): its median
    is the crowd's, against which the crowd stays; the median of what stays is the object's, and
    against it the crowd leaves too (fails with the mask's own median: the crowd stays)."""
    res = np.zeros((20, 100), np.float32)
    res[:, 40:65] = 0.5
    res[:, 65:] = 4.0
    mask = np.ones_like(res, bool)
    kept = moving_part(res, mask)
    assert kept[:, 65:].all() and not kept[:, :65].any()
    # one speed, or a still mask: nothing leaves
    assert moving_part(np.full_like(res, 2.0), mask).all()
    assert moving_part(np.zeros_like(res), mask).all()
