"""Classical baselines to compare against (OpenCV): flow-aligned Debevec HDR video, Laplacian
multi-focus fusion, the two-stage (fusion, then Debevec) all-in-focus HDR of the paper's
comparisons, and for video deblurring unsharp masking and flow-aligned lucky regions.

All take float images in [0,1] (``(N,H,W,3)``) and hand OpenCV 8-bit copies. HDR outputs are
linear float32 with OpenCV's arbitrary scale: compare with ``layercam.core.metrics`` (which aligns
one scale per channel).
"""

from __future__ import annotations

import numpy as np

from layercam.core.colour import REC601, luma, srgb_decode
from layercam.core.errors import LayercamError

__all__ = [
    "debevec_video",
    "laplacian_focus_fusion",
    "lucky_regions",
    "two_stage_mfme",
    "unsharp_mask",
]


# --------------------------------------------------------------------------------------------
# Shared helpers
# --------------------------------------------------------------------------------------------


def _check_stack(images, name: str = "frames") -> np.ndarray:
    a = np.asarray(images)
    if a.ndim != 4 or a.shape[3] != 3 or a.shape[0] < 1:
        raise LayercamError(f"expected {name} (N,H,W,3), got shape {a.shape}")
    a = a.astype(np.float32, copy=False)
    if not np.all(np.isfinite(a)):
        raise LayercamError(f"{name} contain NaN or inf")
    return a


def _check_times(times, n: int) -> np.ndarray:
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    if t.shape != (n,):
        raise LayercamError(f"expected {n} exposure times, got {t.size}")
    if not np.all(np.isfinite(t)) or np.any(t <= 0):
        raise LayercamError("exposure times must be finite and > 0")
    return t


def _u8(img: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.round(np.clip(img, 0.0, 1.0) * 255.0).astype(np.uint8))


def _srgb_linear(img: np.ndarray) -> np.ndarray:
    """Fallback linearisation (inverse sRGB) when the exposures cannot calibrate a CRF."""
    return srgb_decode(np.clip(np.asarray(img, np.float64), 0.0, 1.0))


def _calibrate(stack_u8: list[np.ndarray], times: np.ndarray, samples: int) -> np.ndarray:
    """Debevec CRF calibration -> response ``(256,1,3)`` float32."""
    import cv2

    cal = cv2.createCalibrateDebevec(samples=int(samples), random=False)
    return cal.process(stack_u8, np.asarray(times, np.float32))


def _merge(stack_u8: list[np.ndarray], times: np.ndarray, response: np.ndarray) -> np.ndarray:
    """Debevec merge -> linear HDR ``(H,W,3)`` float32, non-finite values repaired."""
    import cv2

    hdr = cv2.createMergeDebevec().process(stack_u8, np.asarray(times, np.float32), response)
    hdr = np.asarray(hdr, np.float32)
    bad = ~np.isfinite(hdr)
    if bad.any():
        good = hdr[~bad]
        hdr[bad] = float(good.max()) if good.size else 0.0
    return hdr


# --------------------------------------------------------------------------------------------
# Debevec on a video, neighbour aligned with optical flow
# --------------------------------------------------------------------------------------------


def debevec_video(
    frames,
    exposure_times,
    fw=None,
    bw=None,
    calib_pairs: int = 4,
    samples: int = 200,
    flow_method: str = "dis_medium",
    progress: bool = False,
) -> np.ndarray:
    """Per-frame Debevec HDR from each frame and its flow-aligned neighbour.

    frames: ``(T,H,W,3)`` float in [0,1], T >= 2; exposure_times: ``(T,)`` (> 0).
    fw, bw: ``(T-1,H,W,2)`` flows as from ``layercam.vision.flow.compute_flow`` (computed with
    ``flow_method`` when not given). For frame t the neighbour is t+1 (t-1 for the last
    frame), warped into frame t's view with the flow (``flow.warp``).

    The CRF is calibrated ONCE for the clip, for speed: ``cv2.createCalibrateDebevec`` on a
    mosaic of up to ``calib_pairs`` aligned (frame, neighbour) pairs, evenly spaced among the
    pairs with the most common (time, neighbour time) combination of two different times,
    10% borders cropped (where warping repeats edge pixels). Then ``cv2.createMergeDebevec``
    per frame on (frame, warped neighbour) with their times.

    If no pair has two different exposure times, no CRF can be calibrated: the result is the
    inverse-sRGB linearised frame divided by its exposure time.
    Returns ``(T,H,W,3)`` float32 linear HDR (OpenCV's scale).
    """
    from layercam.vision import flow as _flow

    f = _check_stack(frames, "frames")
    n, h, w = f.shape[:3]
    times = _check_times(exposure_times, n)
    if n < 2:
        raise LayercamError("debevec_video needs at least 2 frames")
    if fw is None or bw is None:
        fw, bw = _flow.compute_flow(f, method=flow_method, progress=progress)
    fw = np.asarray(fw, np.float32)
    bw = np.asarray(bw, np.float32)
    if fw.shape != (n - 1, h, w, 2) or bw.shape != fw.shape:
        raise LayercamError(f"flows must be ({n - 1},{h},{w},2), got {fw.shape} and {bw.shape}")

    nb = [t + 1 if t < n - 1 else t - 1 for t in range(n)]
    warped = np.stack(
        [_flow.warp(f[nb[t]], fw[t] if nb[t] == t + 1 else bw[t - 1]) for t in range(n)]
    )
    pair_t = np.stack([times, times[nb]], axis=1)
    distinct = ~np.isclose(pair_t[:, 0], pair_t[:, 1], rtol=1e-6)
    if not distinct.any():
        return (_srgb_linear(f) / times[:, None, None, None]).astype(np.float32)

    # calibration subset: most common (t, t_nb) combination, evenly spaced pairs
    keys = [tuple(np.round(np.log2(pair_t[t]), 6)) for t in range(n)]
    cand = [t for t in range(n) if distinct[t]]
    best = max(set(keys[t] for t in cand), key=lambda k: sum(keys[t] == k for t in cand))
    group = [t for t in cand if keys[t] == best]
    spaced = np.unique(np.linspace(0, len(group) - 1, max(1, calib_pairs)).round())
    pick = [group[int(i)] for i in spaced]
    by, bx = int(round(0.1 * h)), int(round(0.1 * w))
    crop = (slice(by, h - by), slice(bx, w - bx))
    ref = _u8(np.concatenate([f[t][crop] for t in pick], axis=1))
    nbm = _u8(np.concatenate([warped[t][crop] for t in pick], axis=1))
    response = _calibrate([ref, nbm], pair_t[pick[0]], samples)

    out = np.empty((n, h, w, 3), np.float32)
    for t in range(n):
        if distinct[t]:
            out[t] = _merge([_u8(f[t]), _u8(warped[t])], pair_t[t], response)
        else:
            out[t] = _merge([_u8(f[t])], pair_t[t, :1], response)
    return out


# --------------------------------------------------------------------------------------------
# Multi-focus fusion
# --------------------------------------------------------------------------------------------


def laplacian_focus_fusion(images, sigma: float = 2.0, soft: bool = True) -> np.ndarray:
    """All-in-focus fusion of ``(N,H,W,3)`` float images of one exposure -> ``(H,W,3)``.

    Focus measure: squared Laplacian (3x3) of the luma, Gaussian-smoothed (``sigma`` px).
    Each pixel takes the image with the highest energy; with ``soft`` the one-hot decision map
    is Gaussian-smoothed (``sigma``) into blending weights to avoid seams.
    """
    import cv2

    imgs = _check_stack(images, "images")
    if imgs.shape[0] == 1:
        return imgs[0].copy()
    grey = luma(imgs, REC601)
    energy = np.stack(
        [cv2.GaussianBlur(cv2.Laplacian(g, cv2.CV_32F, ksize=3) ** 2, (0, 0), sigma) for g in grey]
    )
    best = np.argmax(energy, axis=0)
    wts = (best[None] == np.arange(imgs.shape[0])[:, None, None]).astype(np.float32)
    if soft:
        wts = np.stack([cv2.GaussianBlur(wi, (0, 0), sigma) for wi in wts])
        wts /= np.maximum(wts.sum(axis=0, keepdims=True), 1e-8)
    return np.einsum("nhw,nhwc->hwc", wts, imgs).astype(np.float32)


# --------------------------------------------------------------------------------------------
# Two-stage all-in-focus HDR (fusion per exposure, then Debevec)
# --------------------------------------------------------------------------------------------


def two_stage_mfme(images, exposure_times, focus_index, samples: int = 200) -> np.ndarray:
    """All-in-focus HDR ``(H,W,3)`` float32 from a static multi-focus multi-exposure stack.

    images: ``(N,H,W,3)`` float in [0,1]; exposure_times, focus_index: ``(N,)``.
    Stage 1: ``laplacian_focus_fusion`` of the images of each exposure time (any order);
    stage 2: Debevec CRF calibration and merge across the fused exposures. With a single
    exposure time the fused image is linearised with inverse sRGB and divided by the time.
    """
    imgs = _check_stack(images, "images")
    n = imgs.shape[0]
    times = _check_times(exposure_times, n)
    fidx = np.asarray(focus_index).reshape(-1)
    if fidx.shape != (n,):
        raise LayercamError(f"expected {n} focus indices, got {fidx.size}")
    uniq = np.unique(np.round(np.log2(times), 6))
    fused, ftimes = [], []
    for ev in uniq:
        sel = np.flatnonzero(np.isclose(np.log2(times), ev, atol=1e-6))
        if len(set(fidx[sel].tolist())) != len(sel):
            raise LayercamError(f"exposure 2**{ev:g}: focus indices repeat ({fidx[sel].tolist()})")
        fused.append(laplacian_focus_fusion(imgs[sel[np.argsort(fidx[sel])]]))
        ftimes.append(float(times[sel[0]]))
    ftimes = np.asarray(ftimes)
    if len(fused) == 1:
        return (_srgb_linear(fused[0]) / ftimes[0]).astype(np.float32)
    stack = [_u8(x) for x in fused]
    response = _calibrate(stack, ftimes, samples)
    return _merge(stack, ftimes, response)


# --------------------------------------------------------------------------------------------
# Video deblurring: unsharp masking, flow-aligned lucky regions
# --------------------------------------------------------------------------------------------


def unsharp_mask(frames, sigma: float = 1.5, amount: float = 1.0) -> np.ndarray:
    """Unsharp masking of each frame: ``f + amount * (f - G_sigma * f)``, clipped to [0,1].

    frames: ``(T,H,W,3)`` float in [0,1] (gamma-encoded, as loaded). Returns ``(T,H,W,3)`` float32.
    What an editor's "sharpen" does: it steepens edges, it does not undo a blur's path.
    """
    import cv2

    f = _check_stack(frames, "frames")
    out = [np.clip(x + amount * (x - cv2.GaussianBlur(x, (0, 0), sigma)), 0.0, 1.0) for x in f]
    return np.stack(out).astype(np.float32)


def lucky_regions(frames, radius: int = 2, window: float = 4.0, agree: float = 0.03,
                  flow_method: str = "dis_medium") -> np.ndarray:
    """Flow-aligned lucky-region selection (after Cho, Wang and Lee, "Video deblurring for
    hand-held cameras using patch-based synthesis", 2012, without its patch synthesis): a hand-held
    clip's blur changes from frame to frame, so each region of frame ``t`` is taken from the
    sharpest of its neighbours ``t - radius .. t + radius`` that shows the same content there.

    For each neighbour ``s``: DIS flow ``t -> s`` (``flow_method``) and back, ``s`` warped into
    ``t``'s view; it may replace ``t`` where the forward-backward check holds and its low-pass
    (Gaussian, 2 px) luma is within ``agree`` of ``t``'s (a misaligned or occluded neighbour
    shows other content). Sharpness: the luma's gradient energy, Gaussian-smoothed over
    ``window`` px. Per pixel the sharpest candidate wins (frame ``t`` itself always a candidate);
    the one-hot choice is smoothed over ``window`` px into blending weights to hide seams.

    frames: ``(T,H,W,3)`` float in [0,1]. Returns ``(T,H,W,3)`` float32 in ``t``'s view.
    """
    import cv2

    from layercam.vision import flow as _flow

    f = _check_stack(frames, "frames")
    n = f.shape[0]
    grey = luma(f, REC601).astype(np.float32)

    def energy(g: np.ndarray) -> np.ndarray:
        gx, gy = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3)
        return cv2.GaussianBlur(gx * gx + gy * gy, (0, 0), window)

    def low(g: np.ndarray) -> np.ndarray:
        return cv2.GaussianBlur(g, (0, 0), 2.0)

    out = np.empty_like(f)
    for t in range(n):
        cands, scores = [f[t]], [energy(grey[t])]
        for s in range(max(0, t - radius), min(n, t + radius + 1)):
            if s == t:
                continue
            fw, bw = _flow.compute_flow(np.stack([f[t], f[s]]), method=flow_method, progress=False)
            ok = _flow.flow_consistency(fw, bw)[0]
            warped = _flow.warp(f[s], fw[0])
            wg = _flow.warp(grey[s], fw[0])
            ok &= np.abs(low(wg) - low(grey[t])) < agree
            e = energy(wg)
            e[~ok] = -1.0
            cands.append(warped)
            scores.append(e)
        best = np.argmax(np.stack(scores), axis=0)
        wts = np.stack([cv2.GaussianBlur((best == i).astype(np.float32), (0, 0), window) for i in range(len(cands))])
        wts /= np.maximum(wts.sum(0, keepdims=True), 1e-8)
        out[t] = np.einsum("nhw,nhwc->hwc", wts, np.stack(cands))
    return np.clip(out, 0.0, 1.0).astype(np.float32)
