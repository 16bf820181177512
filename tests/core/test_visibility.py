"""What a frame sees well: noise estimate, clipped and flat-noise pixels left out."""

from __future__ import annotations

import numpy as np

from layercam.core import visibility


def _texture(h, w, seed=0):
    import cv2

    rng = np.random.default_rng(seed)
    t = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 2.0)
    return (t - t.min()) / (t.max() - t.min())


def test_noise_sigma_reads_the_noise_not_the_texture():
    rng = np.random.default_rng(1)
    g = 0.2 + 0.6 * _texture(128, 128)
    for sigma in (0.005, 0.02):
        est = visibility.noise_sigma(g + rng.normal(0, sigma, g.shape).astype(np.float32))
        assert abs(est - sigma) < 0.25 * sigma, (sigma, est)
    assert visibility.noise_sigma(g) >= visibility.QUANT_SIGMA  # never below 8-bit quantisation


def test_visible_leaves_out_clipped_dark_and_noise_only_pixels():
    rng = np.random.default_rng(2)
    tex = 0.2 + 0.6 * _texture(96, 96)
    f = np.repeat(tex[..., None], 3, -1).astype(np.float32)
    f[:, :32] = 1.0                                                        # clipped
    f[:, 32:64] = 0.5 + rng.normal(0, 0.01, (96, 32, 3)).astype(np.float32)  # flat: noise only
    f[:, 64:] += rng.normal(0, 0.01, (96, 32, 3)).astype(np.float32)         # texture + the same noise
    vis = visibility.visible(np.clip(f, 0, 1))
    assert vis[:, :30].mean() == 0.0
    assert vis[:, 36:60].mean() < 0.05
    assert vis[:, 68:92].mean() > 0.6


def test_clip_levels_and_unrecoverable_pixels():
    """A camera that clips at 248: found from the histogram's spike; a pixel clipped (or black) in
    every frame is unrecoverable, one that some frame saw is not."""
    rng = np.random.default_rng(3)
    f = rng.uniform(0.1, 0.9, (3, 16, 16, 3)).astype(np.float32)
    f[:, :4, :, 0] = 248 / 255        # red clipped at 248 in every frame
    f[0, 4:8, :, 1] = 248 / 255       # green clipped at 248 in one frame only
    f[:, 8:10, :, 2] = 0.0            # blue black in every frame
    levels = visibility.clip_levels(f)
    assert abs(levels[0] * 255 - 247.5) < 1e-3
    bad = visibility.unrecoverable(f, levels)
    assert bad[:4].all() and bad[8:10].all() and not bad[4:8].any() and not bad[10:].any()
    # mid-grey is not clipping
    assert (visibility.clip_levels(np.full((2, 4, 4, 3), 0.5, np.float32)) * 255 == 254.5).all()
