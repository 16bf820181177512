"""Family ``shake_blur``: camera-shake motion blur integrated in linear irradiance."""

from __future__ import annotations

import numpy as np

from layercam.core.errors import LayercamError
from layercam.synth.camera import SynthScene, _alternating, _check_common, _expose, _make_clip
from layercam.synth.canvas import _affine, _canvas_for_path, _emitters_along, _pan_path, _warp, hdr_canvas


# --------------------------------------------------------------------------------------------
# Family: shake_blur
# --------------------------------------------------------------------------------------------


def _shake_curve(rng: np.random.Generator, length: float, n: int) -> np.ndarray:
    """``(n,2)`` offsets along a smooth random curve at s in [-1/2, 1/2], zero at s=0, with
    largest pairwise distance ``length`` (px)."""
    s = np.linspace(-0.5, 0.5, n)
    ang = rng.uniform(0, 2 * np.pi)
    a = np.array([np.cos(ang), np.sin(ang)])
    b = rng.normal(0, 1.2, 2)
    c = rng.normal(0, 1.5, 2)
    p = s[:, None] * a + (s**2)[:, None] * b + (s**3)[:, None] * c
    ext = np.max(np.linalg.norm(p[:, None] - p[None], axis=-1))
    return p * (length / max(ext, 1e-9))


def _splat_kernel(offsets: np.ndarray, m: int) -> np.ndarray:
    """Correlation kernel ``(2m+1,2m+1)``: ``blurred(x) = sum k[m+dy,m+dx] sharp(x+(dx,dy))``."""
    k = np.zeros((2 * m + 1, 2 * m + 1), np.float64)
    for dx, dy in offsets:
        x, y = m + dx, m + dy
        x0, y0 = int(np.floor(x)), int(np.floor(y))
        fx, fy = x - x0, y - y0
        for yy, wy in ((y0, 1 - fy), (y0 + 1, fy)):
            for xx, wx in ((x0, 1 - fx), (x0 + 1, fx)):
                if 0 <= yy <= 2 * m and 0 <= xx <= 2 * m:
                    k[yy, xx] += wx * wy
    return (k / max(k.sum(), 1e-12)).astype(np.float32)


def shake_blur(
    frames: int = 16,
    size: tuple[int, int] = (128, 128),
    max_blur_px: float = 8.0,
    exposures: str = "single",
    ev_step: float = 2.0,
    crf: str = "srgb",
    noise: float = 0.005,
    seed: int = 0,
    speed: tuple[float, float] = (0.5, 1.5),
    canvas: np.ndarray | None = None,
) -> SynthScene:
    """Camera-shake motion blur: each frame is the mean, in linear irradiance, of 9-15
    sub-frame renders along a random smooth trajectory around the frame's pose (a slow pan).

    Blur lengths (largest extent of the trajectory, px) are a shuffled ``linspace(0.2,
    max_blur_px, T)``: some frames sharp-ish, some strongly blurred. ``hdr`` and ``sharp_ldr``
    (noise-free) are the sharp frames at the trajectory's mid point (its pose). exposures:
    "single" (all ``t=1``, background median at 0.18) or "alternating" (``1, 2**ev_step``).
    meta: ``blur_length`` (T,), ``trajectories`` (list of (n,2) pixel offsets of the content
    sample point), ``kernels`` (T,2m+1,2m+1) correlation kernels (see ``_splat_kernel``).

    ``canvas``: a linear irradiance image ``(Hc, Wc, 3)`` (real material) shaken instead of a
    generated one, exposed as given (``exposures="single"``, gain 1); the path is centred on it and
    must fit (a :class:`LayercamError` says how large a canvas it needs).
    """
    h, w = _check_common(frames, size, crf, noise)
    if exposures not in ("single", "alternating"):
        raise LayercamError(f"exposures must be 'single' or 'alternating', got {exposures!r}")
    if max_blur_px < 0:
        raise LayercamError(f"max_blur_px must be >= 0, got {max_blur_px}")
    rng = np.random.default_rng(seed)
    ctr, scale = _pan_path(rng, frames, h, w, speed, 0.0)
    csize, off = _canvas_for_path(ctr, scale, h, w, margin=8, extra=max_blur_px + 2)
    if canvas is None:
        ctr_abs = ctr + off
        n_em = max(3, int(round(csize[0] * csize[1] / 6000)))
        canvas, info = hdr_canvas(csize, rng, emitters=_emitters_along(rng, ctr_abs, h, w, n_em))
    else:
        canvas = np.asarray(canvas, np.float32)
        if canvas.ndim != 3 or canvas.shape[2] != 3 or canvas.shape[0] < csize[0] or canvas.shape[1] < csize[1]:
            raise LayercamError(f"canvas {canvas.shape} cannot hold this path: it needs (H, W, 3) "
                                f"of at least {csize[0]}x{csize[1]}")
        ctr_abs = ctr + off + np.array([canvas.shape[1] - csize[1], canvas.shape[0] - csize[0]]) / 2.0
        if exposures != "single":
            raise LayercamError("a given canvas is exposed as given: exposures must be 'single'")
        info = {"median": 0.18, "emitters": []}  # gain 0.18 / median = 1
    lengths = rng.permutation(np.linspace(0.2, max_blur_px, frames))
    aff = np.stack([_affine(ctr_abs[t, 0], ctr_abs[t, 1], 1.0, h, w) for t in range(frames)])
    m = int(np.ceil(max_blur_px)) + 1
    sharp, blurred, trajs, kernels = [], [], [], []
    for t in range(frames):
        n_sub = int(np.clip(np.ceil(1.5 * lengths[t]) + 1, 9, 15))
        p = _shake_curve(rng, float(lengths[t]), n_sub)
        acc = np.zeros((h, w, 3), np.float32)
        for dx, dy in p:
            a = aff[t].copy()
            a[:, 2] += (dx, dy)
            acc += _warp(canvas, a, h, w)
        blurred.append(acc / n_sub)
        sharp.append(_warp(canvas, aff[t], h, w))
        trajs.append(p.astype(np.float32))
        kernels.append(_splat_kernel(p, m))
    sharp = np.stack(sharp).astype(np.float32)
    blurred = np.stack(blurred).astype(np.float32)
    if exposures == "single":
        times = np.ones(frames, np.float64)
        gain = 0.18 / info["median"]
    else:
        times = _alternating(frames, ev_step)
        gain = 0.9 / float(canvas.max())
    ldr = np.stack([_expose(blurred[t], times[t], gain, crf, noise, rng) for t in range(frames)])
    sharp_ldr = np.stack([_expose(sharp[t], times[t], gain, crf, 0.0, None) for t in range(frames)])
    meta = {
        "family": "shake_blur", "seed": seed, "noise": noise, "exposures": exposures,
        "ev_step": ev_step if exposures == "alternating" else 0.0, "gain": gain,
        "max_blur_px": max_blur_px, "blur_length": lengths.astype(np.float32),
        "trajectories": trajs, "kernels": np.stack(kernels),
        "frame_affine": aff.astype(np.float32), "canvas_median": info["median"],
        "emitters": info["emitters"],
    }
    return SynthScene(_make_clip(ldr, "shake_blur"), times, sharp, crf, None, meta,
                      sharp_ldr=sharp_ldr)
