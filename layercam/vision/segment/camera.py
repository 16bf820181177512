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

from layercam.vision.motion import RANSAC_PX, camera_residuals, grid_points, refit

BORDER = 0.15      # the ring along the frame's edge that shows the camera's motion, a share of the short side
RING_POINTS = 4000  # about this many ring pixels are fitted (a subsample on large frames)


def border_ring(h: int, w: int, width: float | None = None) -> np.ndarray:
    """``(H, W)`` bool: the pixels within ``width`` (default ``BORDER``) of the short side of the frame's edge."""
    r = max(2, int(round((BORDER if width is None else width) * min(h, w))))
    yy, xx = np.mgrid[0:h, 0:w]
    return (yy < r) | (yy >= h - r) | (xx < r) | (xx >= w - r)


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


def pair_residuals(d: np.ndarray, valid: np.ndarray, seed: int = 0) -> tuple[np.ndarray | None, bool]:
    """Residual motion of one frame pair against the camera's: displacements ``d (H, W, 2)``
    (where each pixel lands in the other frame), the camera fitted (:func:`layercam.vision.motion.camera_residuals`)
    on the border ring where ``valid`` and refitted to the whole frame's inliers (LO-RANSAC).
    Returns ``(residual (H, W) float32 px, epipolar)``: the distance to that homography, or the
    smaller of that and the Sampson distance to the ring's epipolar geometry where the fit takes
    one (``epipolar`` True); ``(None, False)`` when the ring has too few valid pixels."""
    res_h, res_f = camera_residuals(d, _ring_sample(valid), _frame_sample(valid), seed)
    if res_h is None:
        return None, False
    return (res_h, False) if res_f is None else (res_f, True)


def border_homographies(fw, seed: int = 0) -> np.ndarray:
    """Per pair ``(T-1, 3, 3)``: the homography (frame t -> t+1 pixels) fitted by RANSAC to the
    forward flow ``(T-1, H, W, 2)`` of the border ring and refitted to the whole frame's inliers
    (:func:`refit`; the identity where it cannot be fitted)."""
    import cv2

    f = np.asarray(fw, np.float32)
    n, h, w = f.shape[:3]
    sel = _ring_sample(np.ones((h, w), bool))
    src = grid_points(h, w)[sel]
    out = np.repeat(np.eye(3)[None], n, 0)
    cv2.setRNGSeed(seed)
    whole = _frame_sample(np.ones((h, w), bool))
    a = grid_points(h, w)[whole]
    for i in range(n):
        hm, _ = cv2.findHomography(src, src + f[i][sel], cv2.RANSAC, RANSAC_PX, maxIters=2000, confidence=0.995)
        if hm is not None and np.all(np.isfinite(hm)) and abs(hm[2, 2]) > 1e-9:
            out[i] = refit(hm / hm[2, 2], a, a + f[i][whole])
    return out
