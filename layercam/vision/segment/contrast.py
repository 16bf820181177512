"""Step 6b: the object moves against the camera more than what clings to it.

A mask grown by edges, colours and the clean plate takes up what touches the object and differs
from the plate: a swaying crowd behind a dancer, a pot near the lens, a rider's still surroundings.
Those move against the camera too, but far less than the object: motion contrast, the cue of
motion saliency (the object is what moves most against its surroundings; Mahadevan and
Vasconcelos 2010, Papazoglou and Ferrari's FST 2013). Each pixel's residual is the larger of its
forward and backward flow's distance (px) to the camera's motion
(:func:`layercam.vision.segment.camera.border_homographies`); mask pixels whose residual is under
``CONTRAST`` times the median residual of the pixels that stay leave, in that frame: the fixed point
of removing them against the median of what is left (the object's own motion, not that of a crowd
the mask took in beside it, sets the level; each round only raises it, so it ends). Then
:func:`layercam.vision.segment.clean.clean_mask` at half its radii; a frame left empty keeps its mask.
"""

from __future__ import annotations

import numpy as np

from layercam.vision.segment.clean import clean_mask

CONTRAST = 0.2  # a mask pixel moving less than this share of the staying pixels' median residual leaves
                # (fitted on DAVIS's training split: 0.1-0.3 alike)


def camera_departure(fw: np.ndarray, bw: np.ndarray, homs: np.ndarray) -> np.ndarray:
    """Each pixel's departure from the camera's motion, ``(T, H, W)`` float32 px: the larger of its
    forward flow's distance to the homography ``homs[t]`` (frame t -> t+1) and its backward flow's
    to ``homs[t-1]``'s inverse (:func:`layercam.vision.flow.residual_motion`); flows ``(T-1, H, W, 2)``."""
    from layercam.vision.flow import residual_motion

    fwd = residual_motion(fw, homs)
    bwd = residual_motion(bw, np.linalg.inv(np.asarray(homs, np.float64)))
    out = np.zeros((len(fwd) + 1,) + fwd.shape[1:], np.float32)
    out[:-1] = fwd
    out[1:] = np.maximum(out[1:], bwd)
    return out


def moving_part(res: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The pixels of ``mask`` (bool ``(H, W)``, not empty) whose residual ``res`` ``(H, W)`` is at
    least ``CONTRAST`` times the median residual of those same pixels (module docstring)."""
    keep = mask
    while True:
        staying = mask & (res >= CONTRAST * np.median(res[keep]))
        if (staying == keep).all():
            return keep
        keep = staying


def contrast_refine(masks: np.ndarray, fw: np.ndarray, bw: np.ndarray, homs: np.ndarray) -> np.ndarray:
    """Masks ``(T, H, W)`` bool without the pixels that move against the camera less than
    ``CONTRAST`` times the median residual of the pixels that stay (:func:`moving_part`); flows ``(T-1, H, W, 2)``,
    ``homs (T-1, 3, 3)`` frame t -> t+1."""
    m = np.asarray(masks) > 0.5
    res = camera_departure(fw, bw, homs)
    out = m.copy()
    for t in range(len(m)):
        if not m[t].any():
            continue
        kept = clean_mask(moving_part(res[t], m[t]), scale=0.5)
        out[t] = kept if kept.any() else m[t]
    return out
