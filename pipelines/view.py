"""Where a sharp frame can be trusted, pixel by pixel (issue 70; the per-frame check of issue 43
compared low-passes and let through frames that lost detail or showed a limb elsewhere).

A deblurred frame ``S`` is right where the camera, applied to it, gives back what the frame
recorded: the model's sharp render taken through its learned blur and tone mapper reproduces the
input ``I`` within the input's noise. The check uses the blur's *shape* without its shift: each
learned PSF moved so that its weighted centre is its pixel (``render_frame(..., centred=True)``,
``B0``). A learned PSF whose centre lies pixels away (it carries content from elsewhere: a limb the
layers hold in another pose, a ghost of another frame) then no longer reproduces the input, while a
right one, whose centre is the exposure's own, is unchanged. The comparison is of the full band,
pixel by pixel, not of low-passes: the lost detail and a doubled edge are in the high frequencies.

Per pixel, ``rho`` is the local mean (a Gaussian window at the blur's scale, :func:`window_sigma`)
of the squared residual ``I - B0`` in units of the input's own noise (measured on the frame,
:func:`layercam.camera.faithful.frame_noise`, per channel, over its well-exposed pixels): about 1
where the model explains the frame within its noise. The trust is ``min(1, 1 / rho)``: the share
of the residual that noise explains; 1 where the model reproduces the input, falling as its error
grows beyond the noise; feathered by the same window, so that it ramps over at least the window's
width wherever the model's error rises. The written frame is ``m S + (1 - m) I``: the sharp render
where it is trusted, the input where it is not, with no seam between them.

Frames are ``(H, W, 3)`` float in [0, 1], in the input's tonality.
"""

from __future__ import annotations

import numpy as np

from layercam.pipelines.runner import Context


WINDOW_MIN_PX = 2.0  # the window's Gaussian sigma, px: at least this, else half the blur generator's reach
SAMPLES_PER_SIGMA = 2  # the re-blurred render is checked every sigma / this px (at least every pixel): the window's
                       # Gaussian passes exp(-2 pi^2) of what lies at that grid's Nyquist frequency; a quarter of the
                       # renders at sigma 4 (docs/measurements.md)


def window_sigma(ctx: Context) -> float:
    """The check's window, px: half the blur generator's reach (``blur.max_offset``, how far the
    camera may have spread a point, so the window holds the pixels that a wrong sharp pixel's blur
    lands on), at least ``WINDOW_MIN_PX`` (without a blur generator: the local mean over a few
    pixels, not one pixel's noise)."""
    s = ctx.resolved.settings
    reach = float(s.blur.max_offset) if s.model.blur == "on" else 0.0
    return max(WINDOW_MIN_PX, reach / 2.0)


def check_stride(sigma: float) -> int:
    """The pixel step of the re-blurred render that the check reads (``SAMPLES_PER_SIGMA``)."""
    return max(1, int(sigma // SAMPLES_PER_SIGMA))


def trust(reblurred: np.ndarray, frame: np.ndarray, sigma: float, stride: int = 1) -> tuple[np.ndarray, dict]:
    """``(H, W)`` float32 in [0, 1]: how far the sharp frame whose re-blurred rendering (centred
    PSFs, through the tone mapper) is ``reblurred`` can be trusted against its input ``frame (H, W,
    3)``, with a window of ``sigma`` px (the module's docstring); ``reblurred`` holds every
    ``stride``-th pixel of every ``stride``-th row (``(ceil(H / stride), ceil(W / stride), 3)``,
    ``render_frame(..., stride=)``), and the local mean read there is resampled to every pixel.
    Also ``{"noise": the input's noise per channel (codes of 255), "kept": the mask's mean}``."""
    import cv2

    from layercam.camera.faithful import disagreement, exposure_weight, frame_noise

    f = np.asarray(frame, np.float32)
    noise = frame_noise(f, exposure_weight(f), 0.0)
    fs = f[::stride, ::stride]
    if np.shape(reblurred) != fs.shape:
        raise ValueError(f"trust: the re-blurred render {np.shape(reblurred)} is not the frame "
                         f"{f.shape} at stride {stride}")
    # every pixel counts, clipped ones too: both clip where the model is as bright as the input saw
    rho = disagreement(fs, np.clip(np.asarray(reblurred, np.float32), 0.0, 1.0), noise,
                       np.ones_like(fs), window=sigma / stride)
    if stride > 1:  # pixel (y, x) of the frame is (y / stride, x / stride) of the grid read
        h, w = f.shape[:2]
        gx, gy = np.meshgrid(np.arange(w, dtype=np.float32) / stride, np.arange(h, dtype=np.float32) / stride)
        rho = cv2.remap(rho.astype(np.float32), gx, gy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    # feathered over the same window: the mask's slope stays under 1 / (sigma sqrt(2 pi)) per px, however
    # sharply the model's error rises (1 / rho alone steps by up to half its range a pixel there)
    m = np.clip(cv2.GaussianBlur((1.0 / np.maximum(rho, 1.0)).astype(np.float32), (0, 0), sigma), 0.0, 1.0)
    return m, {"noise": [round(float(v) * 255, 3) for v in noise], "kept": round(float(m.mean()), 4)}


def blend(sharp: np.ndarray, frame: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``mask * sharp + (1 - mask) * frame``: ``(H, W, 3)`` float32 in [0, 1]."""
    m = np.asarray(mask, np.float32)[..., None]
    return np.clip(m * np.asarray(sharp, np.float32) + (1.0 - m) * np.asarray(frame, np.float32), 0.0, 1.0)
