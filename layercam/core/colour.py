"""Colour: the sRGB transfer curve and luma, in one place.

Numpy arrays go through :func:`srgb_encode`, :func:`srgb_decode` and :func:`luma` here; torch
tensors through ``kornia.color`` (:func:`srgb_encode_torch`), which has the sRGB curve. Two luma
weightings are in use, each for its purpose: Rec. 601 (:data:`REC601`) for the grey images that
flow, sharpness and focus measures work on, Rec. 709 (:data:`REC709`) for the luminance of linear
HDR (display tonemap, synthetic canvases).

>>> import numpy as np
>>> x = np.array([0.0, 0.002, 0.18, 1.0])
>>> np.allclose(srgb_decode(srgb_encode(x)), x)
True
>>> float(luma(np.array([1.0, 1.0, 1.0]), REC709))
1.0
"""

from __future__ import annotations

import numpy as np

REC601 = (0.299, 0.587, 0.114)     # luma of gamma-encoded RGB (grey images for measures)
REC709 = (0.2126, 0.7152, 0.0722)  # luminance of linear RGB


def srgb_encode(x: np.ndarray) -> np.ndarray:
    """Linear ``[0, 1]`` -> sRGB-encoded ``[0, 1]`` (same shape and float type; no clipping)."""
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def srgb_decode(y: np.ndarray) -> np.ndarray:
    """sRGB-encoded ``[0, 1]`` -> linear ``[0, 1]`` (same shape and float type; no clipping)."""
    return np.where(y <= 0.04045, y / 12.92, ((y + 0.055) / 1.055) ** 2.4)


def srgb_encode_torch(x):
    """Linear -> sRGB-encoded for a torch tensor ``(..., 3)``, clamped to ``[0, 1]`` first
    (``kornia.color.linear_rgb_to_rgb``; its other branch is kept finite for gradients)."""
    from kornia.color import linear_rgb_to_rgb

    x = x.clamp(0.0, 1.0)
    return linear_rgb_to_rgb(x.reshape(-1, 3, 1, 1)).reshape(x.shape)


def luma(rgb: np.ndarray, weights=REC601) -> np.ndarray:
    """``(..., 3)`` -> ``(...)``: the weighted sum of the channels, in ``rgb``'s float type."""
    rgb = np.asarray(rgb)
    return rgb @ np.asarray(weights, dtype=rgb.dtype if rgb.dtype.kind == "f" else np.float64)
