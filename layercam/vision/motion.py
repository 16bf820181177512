"""Motion over many frames: pixels followed along the chained flow (:func:`chained_displacements`),
a pair's residual against the static scene (:func:`pair_residuals`: a homography, or an epipolar
model when the clip has parallax) and the
share of pixels that leave the static scene over ``reach`` frames (:func:`long_range_moving_share`,
what the analysis reads to choose two layers).

:func:`pair_residuals` uses the fundamental matrix only when the points it explains beyond the
homography lie in regions that reach the frame's edge (near background runs off the frame; an
object seen whole does not): a degenerate fit can take in any object moving in a straight line.
The foreground finder reads the camera's motion from the frame's border instead
(:mod:`layercam.vision.segment.camera`).

Shapes: flows ``(T-1, H, W, 2)`` in pixels, validity ``(T-1, H, W)`` bool.
"""

from __future__ import annotations

import numpy as np

from layercam.core.geometry import sampson_distance

__all__ = ["chained_displacements", "pair_residuals", "long_range_moving_share"]


def _grid(h: int, w: int) -> np.ndarray:
    from layercam.core.geometry import pixel_grid

    return np.stack(pixel_grid(h, w), -1)


def chained_displacements(fw: np.ndarray, bw: np.ndarray | None, fw_ok: np.ndarray, bw_ok: np.ndarray | None, t: int, kmax: int) -> dict:
    """``{k: (d (H, W, 2), valid (H, W))}`` for ``k = +-1 .. +-kmax`` inside the clip (forward only
    when ``bw`` is None): where each pixel
    of frame ``t`` lands in frame ``t + k`` along the chained flows (``fw[j]``: j -> j+1, ``bw[j]``:
    j+1 -> j), valid where every step lands inside the frame on a forward-backward consistent pixel."""
    import cv2

    T = fw.shape[0] + 1
    h, w = fw.shape[1:3]
    base = _grid(h, w)
    out = {}
    for sgn, flows, oks in ((1, fw, fw_ok), (-1, bw, bw_ok)) if bw is not None else ((1, fw, fw_ok),):
        d = np.zeros((h, w, 2), np.float32)
        v = np.ones((h, w), bool)
        j = t
        for k in range(1, kmax + 1):
            if not 0 <= j + sgn < T:
                break
            i = j if sgn > 0 else j - 1
            p = base + d
            f = cv2.remap(flows[i], p[..., 0], p[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=(np.nan, np.nan, np.nan, np.nan))
            ok = cv2.remap(oks[i].astype(np.float32), p[..., 0], p[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT) > 0.5
            v &= ok & np.isfinite(f).all(-1)
            d = d + np.nan_to_num(f)
            j += sgn
            out[sgn * k] = (d.copy(), v.copy())
    return out


def _edge_fraction(sel: np.ndarray, x2: np.ndarray) -> float:
    """Share of ``sel``'s area (``(H, W)`` bool, after a 3x3 opening) in connected regions that reach
    the frame's edge, or pixels whose match ``x2 (H, W, 2)`` leaves the other frame."""
    import cv2

    h, w = sel.shape
    m = cv2.morphologyEx(sel.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, lab, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    if n <= 1:
        return 0.0
    edge = ~((x2[..., 0] >= 0) & (x2[..., 0] <= w - 1) & (x2[..., 1] >= 0) & (x2[..., 1] <= h - 1))
    edge[0, :] = edge[-1, :] = edge[:, 0] = edge[:, -1] = True
    edge = cv2.dilate(edge.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    touch = np.zeros(n, bool)
    touch[np.unique(lab[edge])] = True
    touch[0] = False
    area = stats[:, cv2.CC_STAT_AREA]
    return float(area[touch].sum() / max(area[1:].sum(), 1))


def pair_residuals(d: np.ndarray, valid: np.ndarray, step: int = 4, ransac_px: float = 1.0, h_inliers: float = 0.8, f_gain: float = 0.1, edge: float = 0.5, seed: int = 0):
    """Residual motion of one frame pair: displacements ``d (H, W, 2)``, fitted where ``valid``.

    Returns ``(res_h, res_f, f_vote)``: the distance (px) to the homography fitted by RANSAC
    (``(H, W)``, None when the pair has too few valid pixels); the smaller of that and the Sampson
    distance to the fundamental matrix (None when the homography already explains at least
    ``h_inliers`` of the points, or the fundamental matrix adds fewer than ``f_gain`` of them); and
    whether the pair votes for the epipolar model (its extra points lie mostly, ``edge``, in regions
    that reach the frame's edge)."""
    import cv2

    h, w = d.shape[:2]
    x1 = _grid(h, w)
    x2 = x1 + d
    sv = valid[::step, ::step].ravel()
    if sv.sum() < 50:
        return None, None, False
    s1, s2 = x1[::step, ::step].reshape(-1, 2)[sv], x2[::step, ::step].reshape(-1, 2)[sv]
    cv2.setRNGSeed(seed)
    hm, inl = cv2.findHomography(s1, s2, cv2.RANSAC, ransac_px, maxIters=2000, confidence=0.995)
    if hm is None or not np.all(np.isfinite(hm)):
        return None, None, False
    p = np.concatenate([x1, np.ones_like(x1[..., :1])], -1) @ hm.T
    z = np.where(np.abs(p[..., 2:]) < 1e-9, 1e-9, p[..., 2:])
    res_h = np.linalg.norm(p[..., :2] / z - x2, axis=-1).astype(np.float32)
    frac_h = float(inl.mean())
    if frac_h >= h_inliers:
        return res_h, None, False
    fm, finl = cv2.findFundamentalMat(s1, s2, cv2.FM_RANSAC, ransac_px, 0.999)
    if fm is None or fm.shape != (3, 3) or float(finl.mean()) < frac_h + f_gain:
        return res_h, None, False
    res_f = np.minimum(res_h, sampson_distance(fm, x1, x2)).astype(np.float32)
    vote = _edge_fraction(valid & (res_h > 2 * ransac_px) & (res_f <= ransac_px), x2) >= edge
    return res_h, res_f, vote


def long_range_moving_share(fw, fw_ok, reach: int = 8, base_px: float = 1.5, rel: float = 0.05) -> np.ndarray:
    """For pairs of frames ``reach`` apart (every ``reach // 2`` frames; fewer when the clip is
    shorter): the share of pixels followed consistently from one to the other whose displacement
    leaves the static scene's model (homography, or the epipolar model where the pair votes for it,
    :func:`pair_residuals`) by more than ``base_px + rel * median displacement``. ``(P,)`` float.
    An object moving 0.1-0.5 px per frame (cows grazing) moves 1-4 px over 8 frames."""
    fw = np.asarray(fw, np.float32)
    T = fw.shape[0] + 1
    k = max(1, min(int(reach), T - 1))
    out = []
    for t in range(0, T - k, max(k // 2, 1)):
        d, v = chained_displacements(fw, None, fw_ok, None, t, k)[k]
        res_h, res_f, vote = pair_residuals(d, v)
        if res_h is None:
            continue
        res = res_f if vote else res_h
        thr = base_px + rel * float(np.median(np.linalg.norm(d[v], axis=-1)))
        out.append(float((v & (res > thr)).mean()))
    return np.asarray(out, np.float32)
