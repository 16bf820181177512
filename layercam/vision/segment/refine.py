"""``segment.refine`` (opt-in): foreground masks from a first fit of the two-layer model."""

from __future__ import annotations

import numpy as np

from layercam.vision.segment.clean import clean_mask


def refine_masks(frames: np.ndarray, background: np.ndarray, alpha: np.ndarray, threshold: float = 0.1) -> np.ndarray:
    """Foreground masks from a first fit of the two-layer model (``segment.refine``): where the frame
    differs from its background layer seen through the camera, near the fitted alpha.

    ``frames``, ``background`` ``(T, H, W, 3)`` pixel values in [0, 1] (the frames and the background
    layer through the learned camera at one exposure), ``alpha`` ``(T, H, W)``. The background
    atlas holds what every frame saw of the background, so a leg the motion masks missed differs from
    it and the wall they took in does not (the residual's largest channel, smoothed 1 px). Per
    frame: alpha > 0.5 eroded by 2% of the short side is kept (an object's inside can match a
    background the object always hid); the ring out to 5% of the short side around it is
    foreground where the residual exceeds ``threshold``; nothing farther (the near background's
    parallax differs from the atlas too); then :func:`clean_mask`. Returns ``(T, H, W)`` bool
    (what the second fit gains: docs/measurements.md)."""
    import cv2

    T, h, w = alpha.shape
    ri = max(1, int(round(0.02 * min(h, w))))
    ro = max(ri + 1, int(round(0.05 * min(h, w))))
    ki = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * ri + 1, 2 * ri + 1))
    ko = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * ro + 1, 2 * ro + 1))
    out = np.zeros((T, h, w), bool)
    for t in range(T):
        res = np.abs(np.asarray(background[t], np.float32) - np.asarray(frames[t], np.float32)).max(-1)
        res = cv2.GaussianBlur(res, (0, 0), 1.0)
        a = (np.asarray(alpha[t]) > 0.5).astype(np.uint8)
        inner = cv2.erode(a, ki) > 0
        ring = cv2.dilate(a, ko) > 0
        out[t] = clean_mask(inner | (ring & (res > threshold)))
    return out
