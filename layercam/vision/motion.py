"""Motion over many frames: pixels followed along the chained flow (:func:`chained_displacements`;
a value voted with its neighbours' along it, :func:`flow_vote`),
a pair's residual against the static scene (:func:`pair_residuals`: a homography, or an epipolar
model when the clip has parallax) and the
share of pixels that leave the static scene over ``reach`` frames (:func:`long_range_moving_share`,
what the analysis reads to choose two layers).

:func:`pair_residuals` uses the fundamental matrix only when the points it explains beyond the
homography lie in regions that reach the frame's edge (near background runs off the frame; an
object seen whole does not): a degenerate fit can take in any object moving in a straight line.
The foreground finder fits the same camera (:func:`camera_residuals`) to the frame's border instead
(:mod:`layercam.vision.segment.camera`).

Shapes: flows ``(T-1, H, W, 2)`` in pixels, validity ``(T-1, H, W)`` bool.
"""

from __future__ import annotations

import numpy as np

from layercam.core.geometry import sampson_distance

__all__ = ["chained_displacements", "flow_vote", "camera_residuals", "pair_residuals", "long_range_moving_share"]

RANSAC_PX = 1.0    # a flow vector within this many pixels of the camera's model is explained by it
H_INLIERS = 0.8    # a homography explaining this share of the points fitted is the camera's whole motion ...
F_GAIN = 0.1       # ... otherwise the epipolar model joins when it explains this much more of them
REFIT = 4          # LO-RANSAC: a homography refitted to the whole frame's inliers at most this often


def grid_points(h: int, w: int) -> np.ndarray:
    """``(H, W, 2)`` float32: each pixel's own coordinates (x, y)."""
    from layercam.core.geometry import pixel_grid

    return np.stack(pixel_grid(h, w), -1)


def chained_displacements(fw: np.ndarray, bw: np.ndarray | None, fw_ok: np.ndarray,
                          bw_ok: np.ndarray | None, t: int, kmax: int) -> dict:
    """``{k: (d (H, W, 2), valid (H, W))}`` for ``k = +-1 .. +-kmax`` inside the clip (forward only
    when ``bw`` is None): where each pixel
    of frame ``t`` lands in frame ``t + k`` along the chained flows (``fw[j]``: j -> j+1, ``bw[j]``:
    j+1 -> j), valid where every step lands inside the frame on a forward-backward consistent pixel."""
    import cv2

    T = fw.shape[0] + 1
    h, w = fw.shape[1:3]
    base = grid_points(h, w)
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
            f = cv2.remap(flows[i], p[..., 0], p[..., 1], cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_CONSTANT,
                          borderValue=(np.nan, np.nan, np.nan, np.nan))
            ok = cv2.remap(oks[i].astype(np.float32), p[..., 0], p[..., 1], cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_CONSTANT) > 0.5
            v &= ok & np.isfinite(f).all(-1)
            d = d + np.nan_to_num(f)
            j += sgn
            out[sgn * k] = (d.copy(), v.copy())
    return out


def flow_vote(values, t: int, fw, bw, fw_ok, bw_ok, reach: int) -> np.ndarray:
    """Frame ``t``'s ``values[t] (H, W)`` averaged with its neighbours' ``values[t + k]``, ``0 < |k| <=
    reach``, each carried into frame ``t`` along the chained flows and counted only where
    :func:`chained_displacements` finds the chain consistent (flows as it takes them, at ``(H, W)``;
    ``values``: anything indexed by frame that holds those frames). Returns ``(H, W)`` float32."""
    from layercam.core.geometry import warp

    own = np.asarray(values[t], np.float32)
    acc, n = own.copy(), np.ones(own.shape, np.float32)
    for k, (d, v) in chained_displacements(fw, bw, fw_ok, bw_ok, t, reach).items():
        acc += np.where(v, warp(np.asarray(values[t + k], np.float32), d), 0.0)
        n += v
    return acc / n


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


def project(hm: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Pixel coordinates ``x (..., 2)`` through the homography ``hm (3, 3)``."""
    p = np.concatenate([x, np.ones_like(x[..., :1])], -1) @ hm.T
    z = np.where(np.abs(p[..., 2:]) < 1e-9, 1e-9, p[..., 2:])
    return p[..., :2] / z


def camera_residuals(d: np.ndarray, sample: np.ndarray, whole: np.ndarray | None = None, seed: int = 0):
    """The camera's motion between two frames, the one fit the analysis and the foreground finder
    share: displacements ``d (H, W, 2)`` (where each pixel lands in the other frame) fitted at the
    pixels ``sample`` ``(H, W)`` bool by RANSAC to a homography (with ``whole`` ``(H, W)`` bool,
    refitted to those pixels' inliers by LO-RANSAC, ``refit``) and, where it leaves more than
    ``1 - H_INLIERS`` of the sample unexplained and the epipolar geometry explains ``F_GAIN`` more,
    to a fundamental matrix. Returns ``(res_h, res_f)``: each pixel's distance (px, ``(H, W)``
    float32) to the homography, and the smaller of that and its Sampson distance to the epipolar
    geometry (None without one); ``(None, None)`` when the sample holds fewer than 50 pixels or
    the homography cannot be fitted."""
    import cv2

    h, w = d.shape[:2]
    x1 = grid_points(h, w)
    x2 = x1 + d
    if sample.sum() < 50:
        return None, None
    s1, s2 = x1[sample], x2[sample]
    cv2.setRNGSeed(seed)
    hm, inl = cv2.findHomography(s1, s2, cv2.RANSAC, RANSAC_PX, maxIters=2000, confidence=0.995)
    if hm is None or not np.all(np.isfinite(hm)):
        return None, None
    if whole is not None:
        hm = refit(hm, x1[whole], x2[whole])
    res_h = np.linalg.norm(project(hm, x1) - x2, axis=-1).astype(np.float32)
    frac_h = float(inl.mean())
    if frac_h >= H_INLIERS:
        return res_h, None
    fm, finl = cv2.findFundamentalMat(s1, s2, cv2.FM_RANSAC, RANSAC_PX, 0.999)
    if fm is None or fm.shape != (3, 3) or float(finl.mean()) < frac_h + F_GAIN:
        return res_h, None
    return res_h, np.minimum(res_h, sampson_distance(fm, x1, x2)).astype(np.float32)


def refit(hm: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """LO-RANSAC's local optimisation (Chum, Matas & Kittler 2003) seeded by a RANSAC model: the
    homography ``hm`` refitted by least squares to the correspondences ``a -> b`` ``(N, 2)`` it
    explains within ``RANSAC_PX``, until its inliers no longer change (at most ``REFIT`` times)."""
    import cv2

    inl = None
    for _ in range(REFIT):
        now = np.linalg.norm(project(hm, a) - b, axis=-1) < RANSAC_PX
        if now.sum() < 8 or (inl is not None and np.array_equal(now, inl)):
            break
        inl = now
        new, _ = cv2.findHomography(a[inl], b[inl], 0)
        if new is None or not np.all(np.isfinite(new)) or abs(new[2, 2]) < 1e-9:
            break
        hm = new / new[2, 2]
    return hm


def pair_residuals(d: np.ndarray, valid: np.ndarray, step: int = 4, edge: float = 0.5, seed: int = 0):
    """Residual motion of one frame pair against the static scene: displacements ``d (H, W, 2)``,
    the camera fitted (:func:`camera_residuals`) to every ``step``-th pixel where ``valid``.

    Returns ``(res_h, res_f, f_vote)``: the distance (px) to the homography (``(H, W)``, None when
    the pair has too few valid pixels); the smaller of that and the Sampson distance to the
    epipolar geometry (None without one); and whether the pair votes for the epipolar model (its
    extra points lie mostly, ``edge``, in regions that reach the frame's edge)."""
    sample = np.zeros(valid.shape, bool)
    sample[::step, ::step] = True
    res_h, res_f = camera_residuals(d, sample & valid, seed=seed)
    if res_f is None:
        return res_h, None, False
    x2 = grid_points(*d.shape[:2]) + d
    vote = _edge_fraction(valid & (res_h > 2 * RANSAC_PX) & (res_f <= RANSAC_PX), x2) >= edge
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
