"""The composite generator (layercam.bench.realsuite.composite) on tiny synthetic material: shapes,
masks, alternating exposures, and frames that are the ground truth through the camera."""

from __future__ import annotations

import numpy as np
import pytest

from layercam.core.errors import LayercamError
from layercam.bench.realsuite.composite import CompositeSpec, compose, expose, filmic


def _material(frames=4, seed=0):
    rng = np.random.default_rng(seed)
    bg = np.exp(rng.normal(-2.0, 1.5, (40, 60, 3))).astype(np.float32)  # radiance over ~9 stops
    fg = rng.uniform(0.2, 0.9, (frames, 30, 40, 3)).astype(np.float32)
    yy, xx = np.mgrid[:30, :40]
    alpha = np.stack([((yy - 15) ** 2 + (xx - 12 - 4 * t) ** 2 < 60).astype(np.float32) for t in range(frames)])
    return bg, fg, alpha


def test_filmic_is_a_monotone_camera_curve_unlike_synth():
    from layercam import synth

    x = np.linspace(0, 1, 257)[:, None].repeat(3, 1)
    y = filmic(x)
    assert np.all(np.diff(y, axis=0) > 0) and np.allclose(y[0], 0) and np.allclose(y[-1], 1)
    assert not np.allclose(y[:, 0], y[:, 2], atol=1e-3)  # a different shoulder per channel
    for name in synth.CRFS:
        assert np.abs(synth.crf_apply(x, name) - y).max() > 0.02


def test_composite_shapes_masks_and_alternating_exposures():
    bg, fg, alpha = _material()
    spec = CompositeSpec(frames=4, size=(24, 32), ev_step=3.0)
    r = compose(bg, fg, alpha, spec)
    assert r["frames"].shape == (4, 24, 32, 3) and r["frames"].dtype == np.uint8
    assert r["hdr"].shape == (4, 24, 32, 3) and r["alpha"].shape == (4, 24, 32)
    assert 0 <= r["alpha"].min() and r["alpha"].max() <= 1 and (r["alpha"] > 0.5).any() and (r["alpha"] < 0.5).any()
    t = r["times"]
    assert t[0] == t[2] and t[1] == t[3] and t[1] / t[0] == pytest.approx(8.0)
    assert r["frames"][1].mean() > r["frames"][0].mean()  # the long frame is brighter
    # the subject moves on its own: its mask is not the same in every frame
    assert not np.array_equal(r["alpha"][0] > 0.5, r["alpha"][3] > 0.5)
    # seeded: the same spec renders the same clip
    assert np.array_equal(compose(bg, fg, alpha, spec)["frames"], r["frames"])


def test_a_still_composite_keeps_its_background_where_the_subject_is_not():
    bg, fg, alpha = _material()
    for still in (False, True):
        r = compose(bg, fg, alpha, CompositeSpec(frames=4, size=(24, 32), ev_step=2.0, still=still))
        clear = (r["alpha"][0] < 1e-3) & (r["alpha"][3] < 1e-3)
        same = np.allclose(r["hdr"][0][clear], r["hdr"][3][clear])
        assert same == still and clear.any()


def test_frames_are_the_ground_truth_through_the_camera():
    bg, fg, alpha = _material(seed=1)
    clean = CompositeSpec(frames=4, size=(24, 32), ev_step=2.0, shot=0.0, read=0.0)
    r = compose(bg, fg, alpha, clean)
    x = r["hdr"].astype(np.float64) * r["times"][:, None, None, None]
    assert np.array_equal(r["frames"], np.round(filmic(x) * 255).astype(np.uint8))
    assert np.array_equal(r["frames"], expose(r["hdr"], r["times"], None, clean))
    noisy = compose(bg, fg, alpha, CompositeSpec(frames=4, size=(24, 32), ev_step=2.0))
    assert np.allclose(noisy["hdr"], r["hdr"])  # noise is in the camera, not in the ground truth
    d = np.abs(noisy["frames"].astype(int) - r["frames"].astype(int))
    assert 0 < d.mean() < 3


def test_too_few_foreground_frames_is_an_error():
    bg, fg, alpha = _material(frames=2)
    with pytest.raises(LayercamError, match="foreground has 2 frames"):
        compose(bg, fg, alpha, CompositeSpec(frames=4, size=(24, 32)))


def test_shaken_still_is_the_still_blurred_along_known_paths():
    """``shake_still``: the still's view per frame, its sharp frame noise-free at the path's mid point,
    and a frame blurred more where its path is longer."""
    from layercam.bench.realsuite.composite import ShakeSpec, shake_still

    rng = np.random.default_rng(1)
    still = np.clip(rng.uniform(0.0, 1.0, (90, 120, 3)), 0, 1).astype(np.float32) ** 2.2  # linear, textured
    spec = ShakeSpec(frames=4, size=(40, 56), max_blur_px=6.0, noise=0.0)
    r = shake_still(still, spec)
    assert r["frames"].shape == (4, 40, 56, 3) and r["frames"].dtype == np.uint8 and r["sharp"].shape == (4, 40, 56, 3)
    lengths = r["blur_length"]
    assert lengths.min() == pytest.approx(0.2) and lengths.max() == pytest.approx(6.0)
    err = [float(np.abs(r["frames"][t] / 255.0 - r["sharp"][t]).mean()) for t in range(4)]
    assert err[int(np.argmax(lengths))] > 3 * err[int(np.argmin(lengths))]
    # exposed as given: a flat still of linear 0.2 is sRGB 0.4845 (code 124) in every frame
    flat = shake_still(np.full((90, 120, 3), 0.2, np.float32), spec)
    assert np.all(flat["sharp"] == np.float32(124 / 255)) and np.all(flat["frames"] == 124)
    with pytest.raises(LayercamError, match="cannot hold this path"):
        shake_still(still[:30, :40], spec)
