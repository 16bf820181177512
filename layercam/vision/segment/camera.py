"""Step 1: the camera's motion, read from the frame's border.

Whatever the camera does (pans, zooms, follows the subject), the frame's border shows the
background: the subject is framed, it seldom fills the edges. So each pair's background motion is
fitted (RANSAC) to the flow of a ring along the border, ``BORDER`` of the short side wide, not to
the whole frame: a subject the camera follows fills much of the frame and keeps its place, and a
fit to every pixel can take its motion for the camera's (DAVIS dog, drift-straight). The ring's
RANSAC model then seeds LO-RANSAC's local optimisation (Chum, Matas & Kittler 2003): it is refitted
by least squares to the whole frame's points it explains, until they no longer change, so the
background inside the frame, which the ring does not see, shapes the model while what moves against
the ring's camera stays out of it. The model is a homography; where the border shows parallax that
a homography cannot explain (a near wall, rocks in front of a hillside) and the epipolar geometry
explains clearly more of it, a pixel's residual is the smaller of the two distances (a static
point of any depth lies on its epipolar line).

Shapes: displacements ``(H, W, 2)`` in pixels (``layercam.vision.flow`` conventions).
"""

from __future__ import annotations

import numpy as np

from layercam.core.geometry import sampson_distance

BORDER = 0.15      # the ring along the frame's edge that shows the camera's motion, a share of the short side
RANSAC_PX = 1.0    # a flow vector within this many pixels of the model is explained by it
H_INLIERS = 0.8    # a homography explaining this share of the ring's points is the camera's whole motion ...
F_GAIN = 0.1       # ... otherwise the epipolar model joins when it explains this much more of them
RING_POINTS = 4000  # about this many ring pixels are fitted (a subsample on large frames)
REFIT = 4          # LO-RANSAC: the border's homography refitted to the whole frame's inliers at most this often


def border_ring(h: int, w: int, width: float | None = None) -> np.ndarray:
    """``(H, W)`` bool: the pixels within ``width`` (default ``BORDER``) of the short side of the frame's edge."""
    r = max(2, int(round((BORDER if width is None else width) * min(h, w))))
    yy, xx = np.mgrid[0:h, 0:w]
    return (yy < r) | (yy >= h - r) | (xx < r) | (xx >= w - r)


def _grid(h: int, w: int) -> np.ndarray:
    from layercam.core.geometry import pixel_grid

    return np.stack(pixel_grid(h, w), -1)


def _frame_sample(valid: np.ndarray) -> np.ndarray:
    """``(H, W)`` bool: a regular lattice of the ``valid`` pixels, spaced so that the border ring
    holds about ``RING_POINTS`` of them."""
    h, w = valid.shape
    step = max(1, int(np.sqrt(border_ring(h, w).sum() / RING_POINTS)))
    sel = np.zeros((h, w), bool)
    sel[::step, ::step] = True
    return sel & valid


def _ring_sample(valid: np.ndarray) -> np.ndarray:
    return _frame_sample(valid) & border_ring(*valid.shape)


def _project(hm: np.ndarray, x: np.ndarray) -> np.ndarray:
    p = np.concatenate([x, np.ones_like(x[..., :1])], -1) @ hm.T
    z = np.where(np.abs(p[..., 2:]) < 1e-9, 1e-9, p[..., 2:])
    return p[..., :2] / z


def refit(hm: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """LO-RANSAC's local optimisation (Chum, Matas & Kittler 2003) seeded by the border's model:
    the homography ``hm`` refitted by least squares to the correspondences ``a -> b`` ``(N, 2)``
    (the whole frame's) it explains within ``RANSAC_PX``, until its inliers no longer change
    (at most ``REFIT`` times). What moves against the border's camera stays out of the fit; the
    background inside the frame, which the ring does not see, joins it."""
    import cv2

    inl = None
    for _ in range(REFIT):
        now = np.linalg.norm(_project(hm, a) - b, axis=-1) < RANSAC_PX
        if now.sum() < 8 or (inl is not None and np.array_equal(now, inl)):
            break
        inl = now
        new, _ = cv2.findHomography(a[inl], b[inl], 0)
        if new is None or not np.all(np.isfinite(new)) or abs(new[2, 2]) < 1e-9:
            break
        hm = new / new[2, 2]
    return hm


def pair_residuals(d: np.ndarray, valid: np.ndarray, seed: int = 0) -> tuple[np.ndarray | None, bool]:
    """Residual motion of one frame pair against the camera's: displacements ``d (H, W, 2)``
    (where each pixel lands in the other frame), fitted on the border ring where ``valid``.
    Returns ``(residual (H, W) float32 px, epipolar)``: the distance to the ring's homography (refitted
    to the whole frame's inliers, :func:`refit`), or the
    smaller of that and the Sampson distance to the ring's epipolar geometry where the homography
    leaves more than ``1 - H_INLIERS`` of the ring unexplained and the epipolar model explains
    ``F_GAIN`` more (``epipolar`` True); ``(None, False)`` when the ring has too few valid pixels."""
    import cv2

    h, w = d.shape[:2]
    x1 = _grid(h, w)
    x2 = x1 + d
    sel = _ring_sample(valid)
    if sel.sum() < 50:
        return None, False
    s1, s2 = x1[sel], x2[sel]
    cv2.setRNGSeed(seed)
    hm, inl = cv2.findHomography(s1, s2, cv2.RANSAC, RANSAC_PX, maxIters=2000, confidence=0.995)
    if hm is None or not np.all(np.isfinite(hm)):
        return None, False
    whole = _frame_sample(valid)
    hm = refit(hm, x1[whole], x2[whole])
    res = np.linalg.norm(_project(hm, x1) - x2, axis=-1).astype(np.float32)
    frac = float(inl.mean())
    if frac >= H_INLIERS:
        return res, False
    fm, finl = cv2.findFundamentalMat(s1, s2, cv2.FM_RANSAC, RANSAC_PX, 0.999)
    if fm is None or fm.shape != (3, 3) or float(finl.mean()) < frac + F_GAIN:
        return res, False
    return np.minimum(res, sampson_distance(fm, x1, x2)).astype(np.float32), True


def border_homographies(fw, seed: int = 0) -> np.ndarray:
    """Per pair ``(T-1, 3, 3)``: the homography (frame t -> t+1 pixels) fitted by RANSAC to the
    forward flow ``(T-1, H, W, 2)`` of the border ring and refitted to the whole frame's inliers
    (:func:`refit`; the identity where it cannot be fitted)."""
    import cv2

    f = np.asarray(fw, np.float32)
    n, h, w = f.shape[:3]
    sel = _ring_sample(np.ones((h, w), bool))
    src = _grid(h, w)[sel]
    out = np.repeat(np.eye(3)[None], n, 0)
    cv2.setRNGSeed(seed)
    whole = _frame_sample(np.ones((h, w), bool))
    a = _grid(h, w)[whole]
    for i in range(n):
        hm, _ = cv2.findHomography(src, src + f[i][sel], cv2.RANSAC, RANSAC_PX, maxIters=2000, confidence=0.995)
        if hm is not None and np.all(np.isfinite(hm)) and abs(hm[2, 2]) > 1e-9:
            out[i] = refit(hm / hm[2, 2], a, a + f[i][whole])
    return out
