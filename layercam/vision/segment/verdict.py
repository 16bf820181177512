"""Step 7: does the clip hold one consistent, independently moving object?

The masks are asked two things. Do they hold together over time: each mask brought into the next
frame along the flow overlaps that frame's mask (the share of either mask's pixels that lie within
``TOLERANCE`` of the other, as the DAVIS boundary measure tolerates 0.008 of the image diagonal:
masks made from a flow cannot be compared more finely than that, and a small person's legs move
more than a plain IoU forgives; the median over the pairs that hold a mask on either side, and a
frame without mask counts as a jump)? Do they cover what moves against the camera
(:mod:`layercam.vision.segment.evidence`) more than what lies around them: the motion evidence
inside the masks over that outside, each a mean over frames (:func:`evidence_contrast`)? Masks
that jump about, or that sit where nothing moves more than the background, are not an object: the
run says so and, without ``--layers``, the analysis chooses one layer
(:func:`layercam.engine.decide.decide`).
"""

from __future__ import annotations

import numpy as np

CONSISTENT = 0.5  # masks that overlap their neighbours' by less than this (median) jump about
TOLERANCE = 0.008  # pixels of one mask within this share of the image diagonal of the other count as overlapping
CONTRAST = 2.0    # masks whose mean evidence is less than this many times the rest's sit on the background's motion


def temporal_iou(masks: np.ndarray, fw: np.ndarray) -> np.ndarray:
    """``(T-1,)``: how well mask t+1, brought into frame t along ``fw[t]``, and mask t overlap: the
    share of both masks' pixels that lie within ``TOLERANCE`` of the image diagonal (at least 1 px)
    of the other mask (1: the same mask; NaN where neither holds a pixel)."""
    import cv2

    from layercam.vision.segment.clean import warp_mask

    m = np.asarray(masks) > 0.5
    r = max(1, int(round(TOLERANCE * float(np.hypot(*m.shape[1:])))))
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    out = np.full(len(m) - 1, np.nan)
    for t in range(len(m) - 1):
        a, b = m[t], warp_mask(m[t + 1], fw[t]) > 0.5
        total = np.count_nonzero(a) + np.count_nonzero(b)
        if total:
            near_a, near_b = cv2.dilate(a.astype(np.uint8), k) > 0, cv2.dilate(b.astype(np.uint8), k) > 0
            out[t] = (np.count_nonzero(a & near_b) + np.count_nonzero(b & near_a)) / total
    return out


def evidence_contrast(masks: np.ndarray, evidence: np.ndarray) -> float:
    """The masks' mean motion evidence over the rest's, each a mean over frames (of the frames that
    hold a mask, and of those with pixels outside it); ``masks (T, H, W)`` bool, at least one pixel
    set, ``evidence (T, H, W)``. Every frame is one sighting of the object, so an object filling
    half of its last frames, where the camera's fit has locked onto it and no motion test sees it,
    does not outweigh its small, moving first frames by its area."""
    ev = np.asarray(evidence, np.float32)
    inside = np.mean([ev[t][m].mean() for t, m in enumerate(masks) if m.any()])
    outside = np.mean([ev[t][~m].mean() for t, m in enumerate(masks) if not m.all()] or [0.0])
    return float(inside) / max(float(outside), 1e-3)


def verdict(masks: np.ndarray, evidence: np.ndarray, fw: np.ndarray) -> dict:
    """``{"found": bool, "reason": str, "consistency": float, "contrast": float}`` for masks
    ``(T, H, W)`` with the motion evidence ``(T, H, W)`` they came from and the forward flows."""
    m = np.asarray(masks) > 0.5
    if len(m) < 2 or not m.any():
        return {"found": False, "reason": "no part of any frame moves against the camera",
                "consistency": 0.0, "contrast": 0.0}
    ious = temporal_iou(m, fw)
    cons = float(np.median(np.nan_to_num(ious[~np.isnan(ious)], nan=0.0))) if (~np.isnan(ious)).any() else 0.0
    contrast = evidence_contrast(m, evidence)
    info = {"consistency": round(cons, 3), "contrast": round(contrast, 2)}
    if cons < CONSISTENT:
        return {"found": False,
                "reason": f"the candidate masks jump between frames (median overlap {cons:.2f} "
                          f"with their neighbours along the flow, < {CONSISTENT})", **info}
    if contrast < CONTRAST:
        return {"found": False,
                "reason": "the candidate masks move like what surrounds them (motion evidence "
                          f"{contrast:.1f}x the rest's, < {CONTRAST:g}x)", **info}
    return {"found": True,
            "reason": f"one object, consistent over time (median overlap {cons:.2f} along the "
                      f"flow), moving {contrast:.1f}x more than the rest", **info}
