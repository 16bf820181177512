"""What a frame can see well: pixels that are neither clipped nor lost in the noise floor and that
carry texture above the frame's noise. Flow between frames several stops apart is evidence of
motion only there: elsewhere one of the two frames shows flat white, flat black or noise, and DIS
fills in whatever its smoothness prior gives (``docs/measurements.md``).

Frames are ``(H, W, 3)`` float in ``[0, 1]``; masks ``(H, W)`` bool.
"""

from __future__ import annotations

import numpy as np

from layercam.core.colour import REC601, luma

# the one definition of clipped and floor values (8-bit codes as values in [0, 1])
CLIP_LEVEL = 254.5 / 255  # a channel at or above this is clipped (8-bit rounding keeps values below it; a camera
                          # that clips lower: clip_levels)
FLOOR_LEVEL = 0.5 / 255   # a channel at or below this is at the floor: the camera recorded nothing there
# well exposed (flow and blur are evidence there): a margin inside those, where noise and a soft shoulder let
# a pixel be read apart from its neighbours
CLIP_HI = 0.97          # no channel at or above this
FLOOR_LO = 4.0 / 255    # grey above this
TEXTURE_SNR = 3.0       # local gradient (Gaussian sigma 1 px) at least this many times its noise response
QUANT_SIGMA = 1.0 / 255 / np.sqrt(12.0)  # the noise of 8-bit quantisation: the least a frame has


def grey(frame: np.ndarray) -> np.ndarray:
    """``(H, W, 3) -> (H, W)`` float32 luma (Rec. 601)."""
    return luma(np.asarray(frame, np.float32), REC601).astype(np.float32)


def texture(g: np.ndarray, sigma: float = 1.0, win: int = 5) -> np.ndarray:
    """Local gradient magnitude ``(H, W)``: Sobel of the Gaussian-smoothed grey image, RMS over a
    ``win x win`` window."""
    import cv2

    b = cv2.GaussianBlur(np.asarray(g, np.float32), (0, 0), sigma)
    gx = cv2.Sobel(b, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(b, cv2.CV_32F, 0, 1, ksize=3)
    return np.sqrt(cv2.blur(gx * gx + gy * gy, (win, win)))


_NOISE_GAIN: dict = {}


def texture_noise_gain(sigma: float = 1.0, win: int = 5) -> float:
    """Median of :func:`texture` on unit white noise: what noise of standard deviation 1 reads as."""
    key = (sigma, win)
    if key not in _NOISE_GAIN:
        rng = np.random.default_rng(0)
        _NOISE_GAIN[key] = float(np.median(texture(rng.standard_normal((128, 128)).astype(np.float32), sigma, win)))
    return _NOISE_GAIN[key]


def noise_sigma(g: np.ndarray, mask: np.ndarray | None = None, flat: float = 0.4) -> float:
    """Noise standard deviation of a grey image (Immerkaer's operator: the second difference
    ``[[1,-2,1],[-2,4,-2],[1,-2,1]]`` has a response of variance ``36 sigma^2`` to white noise),
    averaged as a variance over the flattest ``flat`` share of the ``mask`` pixels (texture
    inflates the operator's response), never below 8-bit quantisation noise."""
    import cv2

    g = np.asarray(g, np.float32)
    k = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    r = cv2.filter2D(g, -1, k, borderType=cv2.BORDER_REFLECT) ** 2 / 36.0
    m = np.ones(g.shape, bool) if mask is None else np.asarray(mask, bool)
    if m.sum() < 64:
        m = np.ones(g.shape, bool)
    t = texture(g, 2.0, 7)
    sel = m & (t <= np.quantile(t[m], flat))
    var = float(r[sel].mean()) if sel.any() else float(r[m].mean())
    return max(float(np.sqrt(var)), QUANT_SIGMA)


def clip_levels(frames: np.ndarray, min_share: float = 0.002, spike: float = 3.0, lowest: float = 0.75) -> np.ndarray:
    """Per channel ``(3,)``: the value at which ``frames (..., 3)`` clip. A camera (or its encoder)
    may clip below 255: the channel's largest value counts as its clipping level when it is at
    least ``lowest``, at least ``min_share`` of the pixels reach it and it is a spike of the
    histogram (``spike`` times as frequent as each of the four code values below it); otherwise
    :data:`CLIP_LEVEL` (what 8-bit rounding keeps)."""
    hists = np.zeros((3, 256), np.int64)  # histograms a frame (and a block of it) at a time: no copy of the clip
    count = 0
    for frame in (frames if np.ndim(frames) == 4 else [frames]):
        flat = np.asarray(frame).reshape(-1, 3)
        count += len(flat)
        for i in range(0, len(flat), 1 << 20):
            q = np.clip(np.round(flat[i : i + (1 << 20)].astype(np.float32) * 255), 0, 255).astype(np.uint8)
            for c in range(3):
                hists[c] += np.bincount(q[:, c], minlength=256)
    out = np.full(3, CLIP_LEVEL, np.float32)
    for c in range(3):
        hist = hists[c]
        top = int(np.flatnonzero(hist).max())
        below = hist[max(top - 4, 0) : top]
        if top >= lowest * 255 and hist[top] >= min_share * count and (below.size == 0
            or hist[top] >= spike * below.max()):
            out[c] = min((top - 0.5) / 255, CLIP_LEVEL)
    return out


def unrecoverable(frames: np.ndarray, levels: np.ndarray | None = None) -> np.ndarray:
    """``(H, W)`` bool: pixels of registered ``frames (N, H, W, 3)`` with a channel clipped (at
    ``levels (3,)``, default :func:`clip_levels`) in every frame or at the 8-bit floor in every
    frame: no frame measured it, so no method can recover it (the real-capture benchmark scores the
    others apart)."""
    f = np.asarray(frames, np.float32)
    lv = clip_levels(f) if levels is None else np.asarray(levels, np.float32)
    return (clipped(f, lv).all(0) | at_floor(f).all(0)).any(-1)


def clipped(frames: np.ndarray, levels: np.ndarray | None = None) -> np.ndarray:
    """``frames (..., 3) -> (..., 3)`` bool: the channels at or above their clipping level
    (``levels (3,)``, default :data:`CLIP_LEVEL`)."""
    return np.asarray(frames) >= (CLIP_LEVEL if levels is None else np.asarray(levels, np.float32))


def at_floor(frames: np.ndarray) -> np.ndarray:
    """``frames (..., 3) -> (..., 3)`` bool: the channels at or below :data:`FLOOR_LEVEL`."""
    return np.asarray(frames) <= FLOOR_LEVEL


def well_exposed(frame: np.ndarray) -> np.ndarray:
    """``(H, W)`` bool: no channel clipped (``< CLIP_HI``) and grey above the 8-bit floor."""
    f = np.asarray(frame, np.float32)
    return (f.max(-1) < CLIP_HI) & (grey(f) > FLOOR_LO)


def visible(frame: np.ndarray) -> np.ndarray:
    """``(H, W)`` bool: well exposed and textured above the frame's noise (local gradient at
    least ``TEXTURE_SNR`` times what the noise alone gives); isolated pixels (noise speckles in a
    dark frame) are opened away."""
    import cv2

    g = grey(frame)
    ok = well_exposed(frame)
    sig = noise_sigma(g, ok)
    vis = ok & (texture(g) > TEXTURE_SNR * sig * texture_noise_gain())
    return cv2.morphologyEx(vis.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)) > 0


def pair_visible(frames: np.ndarray, fw: np.ndarray) -> np.ndarray:
    """``(T-1, H, W)`` bool: pixels of frame ``t`` that frame ``t`` sees well and whose match in
    frame ``t+1`` (along the forward flow ``fw (T-1, H, W, 2)``) frame ``t+1`` sees well."""
    from layercam.core.geometry import warp

    vis = [visible(f) for f in frames]
    out = np.zeros(np.asarray(fw).shape[:3], bool)
    for t in range(len(out)):
        out[t] = vis[t] & (warp(vis[t + 1].astype(np.float32), np.asarray(fw[t], np.float32)) > 0.5)
    return out


def textured(frames: np.ndarray, threshold: float = 0.006, window: float = 0.0125) -> np.ndarray:
    """Where each frame has texture dense flow can follow: ``(T, H, W)`` bool for frames ``(T, H,
    W[, 3])``. The smaller eigenvalue of the grey level's structure tensor (Gaussian window of
    ``window`` times the short side; its square root: grey levels per pixel in the least textured
    direction, so a lone straight edge does not count), over the local mean grey level plus 0.05
    (a frame exposed darker is judged alike), at least ``threshold``; ``threshold <= 0``: all True.
    In a smooth patch (sky, a plain wall) dense flow is interpolated from its edges: at ``--resize
    0.5`` DAVIS parkour's motion masks followed a patch of sky instead of the runner in frames
    15-18 (:func:`layercam.vision.segment.motion_masks` drops parts of its evidence that are mostly
    untextured; per pixel it also lost the Basler clip's person in plain dark clothes:
    docs/measurements.md)."""
    import cv2

    f = np.asarray(frames, np.float32)
    if f.ndim == 4:
        f = np.stack([grey(x) for x in f])
    if threshold <= 0:
        return np.ones(f.shape, bool)
    s = max(window * min(f.shape[1:3]), 0.5)
    out = np.empty(f.shape, bool)
    for t, g in enumerate(f):
        ix = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8
        iy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8
        a, b, c = (cv2.GaussianBlur(v, (0, 0), s) for v in (ix * ix, iy * iy, ix * iy))
        tr, det = a + b, a * b - c * c
        lam = np.sqrt(np.maximum(tr / 2 - np.sqrt(np.maximum(tr * tr / 4 - det, 0)), 0))
        out[t] = lam >= threshold * (cv2.GaussianBlur(g, (0, 0), s) + 0.05)
    return out
