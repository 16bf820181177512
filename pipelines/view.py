"""Whether a sharp frame shows its input's view: deblurring changes detail finer than the blur, not
where things are, so a frame's low-pass must match its blurry input's (issue 43: a frame that misses
is written as the input)."""

from __future__ import annotations

import numpy as np

from layercam.pipelines.runner import Context


VIEW_MIN_DB = 30.0  # low-pass PSNR (dB) a sharp frame must keep to its own input: else it shows another view
VIEW_SIGMA_MIN_PX = 2.0  # the low-pass's Gaussian sigma, px: at least this, else half the blur generator's reach


def view_sigma(ctx: Context) -> float:
    """The low-pass of :func:`view_check`, px: half the blur generator's reach (``blur.max_offset``,
    how far the camera may have spread a point), at least ``VIEW_SIGMA_MIN_PX``; coarser than any blur
    the model can explain, so a right frame's low-pass matches its blurry input's."""
    s = ctx.resolved.settings
    reach = float(s.blur.max_offset) if s.model.blur == "on" else 0.0
    return max(VIEW_SIGMA_MIN_PX, reach / 2.0)


def view_check(rendered: np.ndarray, frame: np.ndarray, sigma: float) -> float:
    """Low-pass PSNR (dB) of a rendered frame ``(H,W,3)`` against its input ``(H,W,3)``, both in [0,1]
    and in the input's tonality, after a Gaussian of ``sigma`` px: deblurring changes detail finer than
    the blur, not where things are, so a frame in its input's view scores high and one shifted or
    showing other content (another frame's pose, a doubled layer) scores low."""
    import cv2

    a = cv2.GaussianBlur(np.clip(rendered, 0.0, 1.0).astype(np.float32), (0, 0), sigma)
    b = cv2.GaussianBlur(np.asarray(frame, np.float32), (0, 0), sigma)
    return float(10.0 * np.log10(1.0 / max(float(np.mean((a - b) ** 2)), 1e-12)))
