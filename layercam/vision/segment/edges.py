"""The finder's edges. Step 4: the motion masks tightened to the object's colour edges by GrabCut
(flow masks overshoot the object by about a flow patch). After step 6: each mask's edge moved to
the colour edge within a few pixels by a guided filter (:func:`guided_refine`)."""

from __future__ import annotations

import numpy as np

ITERATIONS = 4  # GrabCut's iterations
RING = 0.03     # the erosion that is sure foreground and the dilation that may be background, a share of the short side


def grabcut_refine(frame: np.ndarray, mask: np.ndarray, iters: int = ITERATIONS) -> np.ndarray:
    """Tighten a motion mask ``(H, W)`` to the object's colour edges with GrabCut, seeded by the
    mask: eroded mask = sure foreground, mask = probable foreground, a ring around it = probable
    background, the rest = background. Flow-based masks overshoot the object by about a flow patch;
    this pulls them back. Returns ``(H, W)`` bool (the input when GrabCut cannot run)."""
    import cv2

    m = np.asarray(mask) > 0.5
    h, w = m.shape
    if m.sum() < 16 or m.all():
        return m
    u8 = np.ascontiguousarray((np.clip(frame, 0, 1) * 255).astype(np.uint8)[..., ::-1])
    r = max(2, int(round(RING * min(h, w))))
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    mm = m.astype(np.uint8)
    lab = np.full((h, w), cv2.GC_BGD, np.uint8)
    lab[cv2.dilate(mm, k, iterations=2) > 0] = cv2.GC_PR_BGD
    lab[m] = cv2.GC_PR_FGD
    lab[cv2.erode(mm, k, iterations=2) > 0] = cv2.GC_FGD
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    try:
        cv2.grabCut(u8, lab, None, bgd, fgd, iters, cv2.GC_INIT_WITH_MASK)
    except cv2.error:
        return m
    out = (lab == cv2.GC_FGD) | (lab == cv2.GC_PR_FGD)
    return out if out.any() else m


GUIDE_RADIUS = 0.04  # the guided filter's window radius, a share of the short side (fitted on DAVIS's training split)
GUIDE_EPS = 1e-4     # its regulariser, in squared intensity (0-1): below a colour variance of about this, it smooths
VOTE_REACH = 4       # an exported matte: the model's alpha voted with its neighbours' this many frames either side
                     # along the consistent flow (layercam.vision.motion.flow_vote) before the guided filter
                     # (fitted on DAVIS's training split: 1, 2, 3, 4, 6, 8 tried)


def guided_matte(frame: np.ndarray, mask: np.ndarray, radius: float = GUIDE_RADIUS,
                 eps: float = GUIDE_EPS) -> np.ndarray:
    """The mask ``(H, W)`` (> 0.5) filtered with the frame ``(H, W, 3)`` in [0, 1] as the guide (He,
    Sun and Tang 2013, the colour guided filter; their "feathering" of a coarse matte): within each
    window the result is an affine function of the frame's colours, so the matte's edge follows the
    colour edge the window holds (GrabCut's colour models are the clip-wide object's; this is each
    window's own). ``radius``: the window's, a share of the short side. Returns ``(H, W)`` float32 in
    [0, 1]."""
    import cv2

    f = np.asarray(frame, np.float32)
    p = (np.asarray(mask) > 0.5).astype(np.float32)
    r = max(1, int(round(radius * min(p.shape))))

    def box(x):
        return cv2.boxFilter(x, -1, (2 * r + 1, 2 * r + 1), borderType=cv2.BORDER_REFLECT)

    mi = [box(f[..., c]) for c in range(3)]
    mp = box(p)
    cov = np.stack([box(f[..., c] * p) - mi[c] * mp for c in range(3)], -1)
    var = np.stack([np.stack([box(f[..., i] * f[..., j]) - mi[i] * mi[j] + eps * (i == j) for j in range(3)], -1)
                    for i in range(3)], -2)
    a = np.linalg.solve(var, cov[..., None])[..., 0]
    b = mp - sum(a[..., c] * mi[c] for c in range(3))
    q = sum(box(np.ascontiguousarray(a[..., c])) * f[..., c] for c in range(3)) + box(b)
    return np.clip(q, 0.0, 1.0).astype(np.float32)


def guided_refine(frame: np.ndarray, mask: np.ndarray, radius: float = GUIDE_RADIUS,
                  eps: float = GUIDE_EPS) -> np.ndarray:
    """:func:`guided_matte` thresholded at one half: the mask's edge moved to the colour edge within
    a window. Returns ``(H, W)`` bool."""
    return guided_matte(frame, mask, radius, eps) > 0.5
