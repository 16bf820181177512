"""Relative sharpness of two registered frames, tile by tile, on what both frames see well.

For a pair (a, b): b is resampled into a's view by the pair's homography; b's grey levels are
mapped onto a's by matching the quantiles of both, smoothed by ``MATCH_SIGMA``, over the
pixels both see well (exposure and camera curve drop out, the blur does not); then per tile the
band-pass energy (Laplacian of a Gaussian of ``BAND`` px) of
each frame, less what its noise puts there, is compared with that of the other frame blurred by a
Gaussian of sigma ``s``. The ``s`` that brings the sharper frame to the blurrier one's energy is
the tile's relative blur: positive when b is the blurrier, negative when a is.

Only tiles whose texture energy is at least ``TEXTURE_ENERGY`` times the noisier frame's noise
energy count (texture amplitude 8 x the noise): weaker texture is where exposure-dependent effects
(cloud drift over a long exposure, the noise of a short one) read as blur
(``docs/measurements.md``).
"""

from __future__ import annotations

import numpy as np

from layercam.core.visibility import grey, noise_sigma, well_exposed

SIGMAS = (0.0, 0.5, 0.8, 1.2, 1.6, 2.0, 2.5, 3.0, 4.0, 5.0)
BAND = 1.0              # px: the band-pass scale
TEXTURE_ENERGY = 64.0   # a tile counts when its band energy is this many times the noise's
MIN_COVER = 0.5         # ... and at least this share of its pixels is well exposed in both frames
MATCH_SIGMA = 4.0       # px: the scale at which the two frames' grey levels are matched


def tile_size(h: int, w: int) -> int:
    """Tiles of 32 px, smaller on small frames (at least 4 x 4 tiles, at least 12 px)."""
    return int(max(12, min(32, min(h, w) // 4)))


def _band(g: np.ndarray, s: float) -> np.ndarray:
    import cv2

    b = cv2.GaussianBlur(g, (0, 0), float(np.hypot(s, BAND)))
    return cv2.Laplacian(b, cv2.CV_32F, ksize=3)


_KAPPA: dict = {}


def band_noise_gain(s: float) -> float:
    """Band energy of unit white noise after a blur of sigma ``s`` (sum of squared kernel weights)."""
    if s not in _KAPPA:
        d = np.zeros((65, 65), np.float32)
        d[32, 32] = 1.0
        _KAPPA[s] = float((_band(d, s) ** 2).sum())
    return _KAPPA[s]


def _tile_mean(x: np.ndarray, m: np.ndarray, ts: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean of ``x`` over the ``m`` pixels of each ``ts x ts`` tile, and each tile's share of ``m``."""
    h, w = x.shape
    ny, nx = h // ts, w // ts
    xs = (x * m)[: ny * ts, : nx * ts].reshape(ny, ts, nx, ts).sum((1, 3))
    ms = m[: ny * ts, : nx * ts].reshape(ny, ts, nx, ts).sum((1, 3))
    return xs / np.maximum(ms, 1.0), ms / float(ts * ts)


def _energies(g: np.ndarray, m: np.ndarray, sigma: float, ts: int) -> np.ndarray:
    """``(len(SIGMAS), ny, nx)``: per tile, band energy of ``g`` blurred by each sigma, less the noise's."""
    return np.stack([_tile_mean(_band(g, s) ** 2, m, ts)[0] - sigma**2 * band_noise_gain(s) for s in SIGMAS])


def _smooth_within(g: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Gaussian smoothing (``MATCH_SIGMA``) of ``g`` over the pixels of ``m`` only (normalised
    convolution: clipped neighbours do not leak in)."""
    import cv2

    mf = m.astype(np.float32)
    num = cv2.GaussianBlur(g * mf, (0, 0), MATCH_SIGMA)
    return num / np.maximum(cv2.GaussianBlur(mf, (0, 0), MATCH_SIGMA), 1e-6)


def _interp_extend(x: np.ndarray, xp: np.ndarray, fp: np.ndarray, tail: int = 16) -> np.ndarray:
    """``np.interp`` continued linearly past both ends with the slope over the last ``tail``
    knots: raw grey levels reach beyond the smoothed quantiles, and clamping them would take
    contrast away."""
    y = np.interp(x, xp, fp)
    lo_slope = (fp[tail] - fp[0]) / max(xp[tail] - xp[0], 1e-9)
    hi_slope = (fp[-1] - fp[-1 - tail]) / max(xp[-1] - xp[-1 - tail], 1e-9)
    y = np.where(x < xp[0], fp[0] + (x - xp[0]) * lo_slope, y)
    return np.where(x > xp[-1], fp[-1] + (x - xp[-1]) * hi_slope, y)


def _blur_to_reach(table: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Per tile, the sigma at which the energies ``table (S, n)`` fall to ``target (n,)``
    (interpolated in log energy; 0 when already below, the largest sigma when never)."""
    lt = np.log(np.maximum(table, 1e-12))
    lg = np.log(np.maximum(target, 1e-12))
    out = np.zeros(lg.shape, np.float32)
    for i in range(lg.shape[0]):
        col = lt[:, i]
        k = int(np.searchsorted(-col, -lg[i]))
        if k <= 0:
            continue
        if k >= len(SIGMAS):
            out[i] = SIGMAS[-1]
            continue
        f = (lg[i] - col[k - 1]) / (col[k] - col[k - 1]) if col[k] != col[k - 1] else 0.0
        out[i] = SIGMAS[k - 1] + f * (SIGMAS[k] - SIGMAS[k - 1])
    return out


def pair_relative_blur(fa: np.ndarray, fb: np.ndarray, hom: np.ndarray | None = None,
                       exclude: np.ndarray | None = None) -> np.ndarray:
    """Signed relative blur (Gaussian sigma, px) of frame ``fb`` against ``fa`` (both ``(H, W, 3)``
    in [0, 1]) on each tile both see well: ``(n,)`` float32, positive where ``fb`` is the blurrier.
    ``hom (3, 3)`` maps ``fa``'s pixels to ``fb``'s (identity when None); ``exclude (H, W)`` bool
    marks pixels of ``fa`` to leave out (content that moves on its own). Empty when no tile counts."""
    import cv2

    h, w = fa.shape[:2]
    hom = np.eye(3) if hom is None else np.asarray(hom, np.float64)
    flags = cv2.WARP_INVERSE_MAP
    ga = grey(fa)
    gb = cv2.warpPerspective(grey(fb), hom, (w, h), flags=cv2.INTER_LINEAR | flags, borderMode=cv2.BORDER_REPLICATE)
    inside = cv2.warpPerspective(np.ones((h, w), np.uint8), hom, (w, h),
                                 flags=cv2.INTER_NEAREST | flags, borderValue=0) > 0
    okb = cv2.warpPerspective(well_exposed(fb).astype(np.uint8), hom, (w, h),
                              flags=cv2.INTER_NEAREST | flags, borderValue=0) > 0
    m = well_exposed(fa) & okb & inside
    if exclude is not None:
        m &= ~(cv2.dilate(np.asarray(exclude, np.uint8), np.ones((5, 5), np.uint8)) > 0)
    m = cv2.erode(m.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0  # clipping edges are not texture
    if m.sum() < 256:
        return np.zeros(0, np.float32)
    # grey levels of b onto a's: quantiles matched on both smoothed well beyond the blur measured,
    # so that the contrast a blur takes away is not given back (matched unsmoothed, a blurred copy
    # read as about half its blur)
    q = np.linspace(0.0, 1.0, 257)
    qa = np.quantile(_smooth_within(ga, m)[m], q)
    qb = np.quantile(_smooth_within(gb, m)[m], q) + np.arange(q.size) * 1e-9  # strictly increasing
    gb = _interp_extend(gb, qb, qa).astype(np.float32)
    sa, sb = noise_sigma(ga, m), noise_sigma(gb, m)
    ts = tile_size(h, w)
    mf = m.astype(np.float32)
    ea, eb = _energies(ga, mf, sa, ts), _energies(gb, mf, sb, ts)
    cover = _tile_mean(mf, mf, ts)[1]
    valid = (cover >= MIN_COVER) & (np.maximum(ea[0], eb[0]) > TEXTURE_ENERGY * max(sa, sb) ** 2 * band_noise_gain(0.0))
    ea, eb = ea[:, valid], eb[:, valid]
    b_blurrier = _blur_to_reach(ea, eb[0])
    a_blurrier = _blur_to_reach(eb, ea[0])
    return np.where(b_blurrier >= a_blurrier, b_blurrier, -a_blurrier).astype(np.float32)
