"""Relative blur of two frames, tile by tile: a blurred copy reads as blur, an exposure change does not."""

from __future__ import annotations

import numpy as np

from layercam.vision import sharpness


def _scene(h=128, w=128, seed=0):
    """Texture at several scales, with flat patches (as photographs have)."""
    import cv2

    rng = np.random.default_rng(seed)
    t = sum(a * cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), s) * s
            for a, s in ((1.0, 1.0), (0.6, 3.0), (0.5, 8.0)))
    t[::32, :] = t[:, ::32] = 0.0
    t[8:24, 8:24] = t[70:100, 40:80] = float(np.median(t))
    t = (t - t.min()) / (t.max() - t.min())
    return np.repeat(t[..., None], 3, -1) * 0.8 + 0.1


def _camera(lin, ev, rng, noise=0.001):
    v = np.clip(lin * 2.0**ev + rng.normal(0, noise, lin.shape), 0, 1) ** (1 / 2.2)
    return (np.round(v * 255) / 255).astype(np.float32)


def test_blurred_copy_reads_its_blur_with_its_sign():
    import cv2

    s = _scene()
    for sigma in (1.2, 2.0):
        b = cv2.GaussianBlur(s, (0, 0), sigma)
        tiles = sharpness.pair_relative_blur(s, b)
        assert len(tiles) >= 9
        assert abs(float(np.median(tiles)) - sigma) < 0.4, (sigma, np.median(tiles))
        assert float(np.median(sharpness.pair_relative_blur(b, s))) < -0.8  # a is the blurrier one


def test_exposure_change_is_not_blur():
    """3 stops apart through a gamma curve, noise and 8-bit quantisation, the bright frame clipped
    in places: no tile reads as blurred by 0.8 px or more."""
    rng = np.random.default_rng(3)
    lin = _scene() ** 2.2 * 0.9
    dark, bright = _camera(lin, -3.0, rng), _camera(lin, 0.5, rng)
    assert (bright >= 0.97).any()
    tiles = sharpness.pair_relative_blur(dark, bright)
    assert len(tiles) > 0 and float(np.mean(np.abs(tiles) >= 0.8)) < 0.2, tiles


def test_excluded_pixels_are_not_compared():
    s = _scene()
    assert len(sharpness.pair_relative_blur(s, s, exclude=np.ones(s.shape[:2], bool))) == 0
