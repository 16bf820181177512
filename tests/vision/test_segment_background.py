"""The finder's clean plate: the background the neighbours show, its shortcuts, and a limb the flow
missed found against it."""

from __future__ import annotations

import numpy as np
import pytest

from layercam.core import metrics
from layercam.vision import segment
from layercam.vision.segment.background import _matched, _nan_median, background_refine, texture_refine

from test_segment import _square_clip


def test_background_refine_finds_a_missed_limb_at_alternating_exposures():
    """Masks that miss a strip of the object (a limb the flow was too coarse for) and take in a strip
    of background beside it (flow bleeding) are corrected against the background the neighbours
    show, though every other frame is shot at another exposure through another curve."""
    T, size, side = 10, 96, 20
    frames, truth, _ = _square_clip(T=T, size=size, side=side, seed=3)
    frames[1::2] = frames[1::2] ** 0.6  # the other exposure, through another curve
    homs = np.stack([np.array([[1, 0, -1.0], [0, 1, -0.5], [0, 0, 1]])] * (T - 1))  # the pan, frame t -> t+1
    given = truth.copy()
    limb, bleed = np.zeros_like(truth), np.zeros_like(truth)
    for t in range(T):
        ys, xs = np.nonzero(truth[t])
        x1, y0 = xs.max() + 1, ys.min()
        limb[t, y0 : y0 + side, x1 - 4 : x1] = True   # the object's right edge, missed
        bleed[t, y0 - 4 : y0, x1 - side : x1 - 4] = True  # background above it, taken in
    given = (truth & ~limb) | bleed
    out, _, _ = background_refine(frames, given.astype(np.float32), homs)
    assert out.shape == truth.shape and out.dtype == bool
    before = np.mean([metrics.iou(given[t], truth[t]) for t in range(T)])
    after = np.mean([metrics.iou(out[t], truth[t]) for t in range(T)])
    assert after > 0.85 and after > before + 0.15, (before, after)
    assert out[limb].mean() > 0.8  # found in every frame, either exposure
    assert out[bleed].mean() < 0.6  # partly: the slow object hid that background in most neighbours
    off = segment.foreground_bootstrap(frames, None, given.astype(np.float32))  # given masks are kept as given
    assert np.array_equal(off["masks"] > 0.5, given)


def test_background_median_and_level_map_shortcuts():
    """The background check's shortcuts give what the plain numpy calls give: the one-sort median
    equals ``np.nanmedian`` (samples missing in every channel), and on a frame above the sample
    limit the subsampled, tabled level map stays within a level of the exact one."""
    rng = np.random.default_rng(0)
    stack = rng.uniform(0, 1, (7, 20, 30, 3)).astype(np.float32)
    stack[rng.uniform(size=(7, 20, 30)) < 0.4] = np.nan
    stack[:, 0, 0] = np.nan  # a pixel no neighbour sees
    count = (~np.isnan(stack[..., 0])).sum(0)
    with np.errstate(all="ignore"), pytest.warns(RuntimeWarning):
        want = np.nanmedian(stack, 0)
    got = _nan_median(stack, count)
    assert np.allclose(got[count > 0], want[count > 0]) and np.isnan(got[0, 0]).all()
    src = rng.uniform(0, 1, (400, 400, 3)).astype(np.float32)  # 160,000 pixels: above the limit
    dst = src**0.6
    ok = np.ones((400, 400), bool)
    fast = _matched(src, dst, ok)
    exact = _matched(src, dst, ok, samples=10**7)
    assert np.abs(fast - exact).max() < 1 / 255
    assert np.abs(fast - dst).max() < np.abs(exact - dst).max() + 1 / 255 < 0.03  # 65 levels of a curve


def test_texture_refine_drops_the_objects_shadow_and_keeps_the_object():
    """A mask that holds the object and its shadow (the plate's texture darkened to half, with a soft
    edge) loses the shadow and keeps the object, whose texture is its own; where the plate is unknown
    (NaN) the shadow stays, and a mask that is all plate keeps itself rather than vanish."""
    import cv2

    rng = np.random.default_rng(0)
    h, w = 64, 96
    plate = rng.uniform(0.2, 0.9, (h, w, 3)).astype(np.float32)
    obj = np.zeros((h, w), bool)
    obj[16:40, 20:44] = True
    core = np.zeros((h, w), np.float32)
    core[40:52, 20:60] = 1
    shade = cv2.GaussianBlur(core, (0, 0), 2.0)  # the penumbra
    frame = plate * (1 - 0.5 * shade)[..., None]
    frame[obj] = rng.uniform(0.2, 0.9, (obj.sum(), 3))
    shadow = (shade > 0.5) & ~obj
    mask = obj | shadow
    out = texture_refine(frame[None], mask[None], plate[None])[0]
    away = shadow.copy()
    away[:43] = False  # the shadow 3 px or more from the object (a window beside it holds the object too)
    assert out[obj].mean() > 0.95 and out[away].mean() < 0.05 and out[shadow].mean() < 0.3, (
        out[obj].mean(), out[away].mean(), out[shadow].mean())
    unknown = plate.copy()
    unknown[shadow] = np.nan
    assert texture_refine(frame[None], mask[None], unknown[None])[0][shadow].mean() > 0.95
    assert np.array_equal(texture_refine(plate[None], shadow[None], plate[None])[0], shadow)
