"""Step 4: the motion masks tightened to the object's colour edges by GrabCut: flow masks overshoot
the object by about a flow patch."""

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
