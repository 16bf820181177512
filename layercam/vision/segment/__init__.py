"""The foreground finder: the moving object of a two-layer clip, found without a detector.

The method is background-first (as layered neural rendering is): the camera's motion is read
from the frame's border, what persistently moves against it seeds the foreground, and the seed is
grown to the object by its edges, by the clean plate its neighbours show, and by its colours
learned over the whole clip. One step per module:

1. :mod:`~layercam.vision.segment.camera`: the camera's motion per frame pair, fitted to the flow of a
   ring along the frame's border (a homography, the epipolar geometry where the border shows
   parallax): a subject the camera follows keeps its place and cannot pass for the background.
2. :mod:`~layercam.vision.segment.evidence`: each pixel followed along the flow to frames 1, 2, 4, ...
   ``reach`` away; it moves in a pair where its residual exceeds ``k_sigma`` times the pair's
   measured noise (its robust spread) and the flow's precision.
3. :mod:`~layercam.vision.segment.moving`: the evidence voted with its neighbours along the flow, counted
   where the frame has texture the flow can follow, one object per frame, still frames filled from
   the nearest frame that holds the object at its typical size; where the clip's largest moving
   parts are a dynamic texture (:mod:`~layercam.vision.segment.dynamic`: a stream, ripples, their
   outline keeping its place while the flow inside moves), the one track of parts, followed along
   the flow over the clip, whose outline travels with its flow, and otherwise the track of the
   largest area (the ``travel`` step: one object for the clip, not the largest part of each frame).
4. :mod:`~layercam.vision.segment.edges`: GrabCut pulls each mask to the object's colour edges.
5. :mod:`~layercam.vision.segment.background`: the clean plate (neighbours registered by the camera's
   motion, their object left out) adds limbs the flow missed and drops background the flow smeared.
6. :mod:`~layercam.vision.segment.colour`: a graph cut on the object's colours learned over the clip grows
   the masks to the whole object where the frame differs from the clean plate, and where a frame's
   mask lost part of the object its neighbour's, carried along the flow, offers it back; pixels that
   show the clean plate's texture (in the object's shadow too) leave
   (:func:`~layercam.vision.segment.background.texture_refine`); pixels that move against the camera
   far less than the rest of their mask leave (:mod:`~layercam.vision.segment.contrast`); a guided filter
   (:func:`~layercam.vision.segment.edges.guided_refine`) then moves each mask's edge to the colour
   edge within a few pixels.
7. :mod:`~layercam.vision.segment.verdict`: masks that jump about or move like their surroundings are no
   object: the run says so.

:mod:`~layercam.vision.segment.mapping` turns the masks into the foreground layer's starting mapping,
:mod:`~layercam.vision.segment.store` keeps them on disk, :mod:`~layercam.vision.segment.detect` (``segment.detector``)
and ``--masks`` replace them. Every step's share of the result is measured in ``docs``
(the ablation table). Shapes: frames ``(T, H, W, 3)``, flows ``(T-1, H, W, 2)`` in pixels, masks
``(T, H, W)``.
"""

from __future__ import annotations

import numpy as np

from layercam.core.config import SegmentConfig
from layercam.vision.segment.clean import clean_mask
from layercam.vision.segment.mapping import foreground_mappings, object_motion
from layercam.vision.segment.evidence import offsets as motion_offsets
from layercam.vision.segment.moving import motion_masks
from layercam.vision.segment.store import load_masks, mask_coverage, save_masks, sure_pixels

__all__ = ["SegmentConfig", "STEPS", "foreground_bootstrap", "motion_masks", "motion_offsets",
           "clean_mask", "object_motion", "foreground_mappings", "sure_pixels", "load_masks",
           "save_masks"]

# the optional steps after the motion masks (each measured: the ablation)
STEPS = ("travel", "grabcut", "background", "colour", "texture", "contrast", "guided")
WORK_SHORT = 240  # the finder sees frames at most this many pixels on the short side (masks are upsampled to the
                  # frame; training refines alpha's edges at the frame's size): its cost stays under a second a frame


def flow_at(f, work: tuple[int, int]) -> np.ndarray:
    """One flow ``(h, w, 2)`` at the size ``work`` (area averaging), in that size's pixels; float32."""
    import cv2

    f = np.asarray(f, np.float32)
    h, w = f.shape[:2]
    if (h, w) == tuple(work):
        return f
    return cv2.resize(f, (work[1], work[0]), interpolation=cv2.INTER_AREA) * np.float32([work[1] / w, work[0] / h])


def check_at(m, work: tuple[int, int]) -> np.ndarray:
    """One flow check ``(h, w)`` at the size ``work`` (nearest pixel); bool."""
    import cv2

    m = np.asarray(m, bool)
    if m.shape == tuple(work):
        return m
    return cv2.resize(m.astype(np.uint8), (work[1], work[0]), interpolation=cv2.INTER_NEAREST) > 0


def _working(frames: np.ndarray, flows: dict) -> tuple[np.ndarray, dict]:
    """Frames and flows at the finder's working size (``WORK_SHORT``; unchanged when smaller)."""
    from layercam.vision.scale import resize_frames, working_size

    h, w = frames.shape[1:3]
    work = working_size((h, w), WORK_SHORT)
    if work == (h, w):
        return frames, flows
    out = {k: np.stack([flow_at(x, work) for x in flows[k]]) for k in ("fw", "bw")}
    for k in ("fw_ok", "bw_ok"):
        if flows.get(k) is not None:
            out[k] = np.stack([check_at(x, work) for x in flows[k]])
    return resize_frames(frames, work), out


def find_foreground(frames: np.ndarray, flows: dict, cfg: SegmentConfig,
                    steps: tuple = STEPS) -> tuple[np.ndarray, dict]:
    """The finder itself (module docstring): masks ``(T, H, W)`` float32 in {0, 1} and an info
    dict whose ``"verdict"`` says whether one consistent moving object was found. ``flows`` holds
    ``fw``, ``bw`` (and optionally ``fw_ok``, ``bw_ok``) at the frames' size; ``steps``: the
    optional steps to run (all of :data:`STEPS` unless ablating). Frames larger than ``WORK_SHORT``
    on the short side are segmented at that size and the masks upsampled."""
    from layercam.vision.segment.camera import border_homographies
    from layercam.vision.segment.evidence import motion_evidence
    from layercam.vision.segment.moving import check_flows, flow_checks
    from layercam.vision.segment.verdict import verdict

    import cv2

    T, h, w = frames.shape[:3]
    check_flows(flows["fw"], flows["bw"])
    frames, flows = _working(frames, flows)
    fw, bw = check_flows(flows["fw"], flows["bw"])
    fo, bo = flow_checks(fw, bw, flows.get("fw_ok"), flows.get("bw_ok"))
    homs = border_homographies(fw) if {"travel", "background", "contrast"} & set(steps) else None
    masks, info = motion_masks(fw, bw, fo, bo, cfg=cfg, frames=frames, homs=homs if "travel" in steps else None)
    evidence = info.pop("evidence")
    if "grabcut" in steps:
        from layercam.vision.segment.edges import grabcut_refine

        masks = np.stack([grabcut_refine(frames[t], masks[t]) for t in range(T)]).astype(np.float32)
    if "background" in steps:
        from layercam.vision.segment.background import background_refine
        from layercam.vision.segment.clean import fill_still_frames

        masks, rel, plate = background_refine(frames, masks, homs)
        if "colour" in steps:
            from layercam.vision.segment.colour import colour_cut

            # frames the check emptied start again from their neighbours'
            masks = colour_cut(frames, fill_still_frames(masks, fw, bw)[0], rel, fw, bw)
        if "texture" in steps:
            from layercam.vision.segment.background import texture_refine

            masks = texture_refine(frames, masks, plate)
    if "contrast" in steps:
        from layercam.vision.segment.contrast import contrast_refine

        masks = contrast_refine(masks, fw, bw, homs)
    if "guided" in steps:
        from layercam.vision.segment.edges import guided_refine

        masks = np.stack([guided_refine(frames[t], masks[t]) if masks[t].any() else masks[t] > 0.5
                          for t in range(T)])
    masks = np.asarray(masks, np.float32)
    info["verdict"] = verdict(masks, evidence, fw)
    if masks.shape[1:] != (h, w):
        info["working_size"] = list(masks.shape[1:])
        masks = np.stack([cv2.resize(m, (w, h), interpolation=cv2.INTER_LINEAR) > 0.5
                          for m in masks]).astype(np.float32)
    info["coverage_final"] = float(masks.mean())
    return masks, info


def detector_masks(frames: np.ndarray, masks: np.ndarray, cfg: SegmentConfig,
                   progress: bool = False) -> tuple[np.ndarray, dict]:
    """The motion ``masks`` ``(T, H, W)`` replaced by the instances of the local detector file
    ``cfg.detector`` (:mod:`layercam.vision.segment.detect`) that lie in them, on ``frames``
    ``(T, H, W, 3)`` of the masks' size; returns the masks and what was picked."""
    from layercam.vision.segment.detect import detect_instances, pick_instances

    found = detect_instances(frames, cfg.detector, cfg.detector_score, cfg.detector_size, progress)
    return pick_instances(found, masks, cfg.detector_overlap)


def foreground_bootstrap(frames: np.ndarray, flows: dict | None, masks: np.ndarray | None = None,
                         cfg: SegmentConfig | None = None, progress: bool = False) -> dict:
    """What a two-layer scene starts from: ``{"h0": (T, 3, 3), "masks": (T, H, W) | None,
    "computed": bool, "how": str, "info": dict}``.

    ``masks`` given by the user win; otherwise, with flow (``flows`` holds ``fw``, ``bw``,
    ``fw_ok``, ``bw_ok`` at the frames' size, as :func:`layercam.vision.flow_store.at_frame_size` gives them),
    :func:`find_foreground`'s masks (``info["verdict"]`` says whether they hold one object), then,
    with ``cfg.detector``, a local Mask R-CNN's instances that lie in them (:mod:`layercam.vision.segment.detect`);
    with neither (one frame), no masks and the identity mapping. ``cfg``: the finder's settings
    (``segment``); None: their defaults (the one place the finder builds them; every function below
    takes the settings it is given).
    """
    cfg = cfg or SegmentConfig()
    T, h, w = frames.shape[:3]
    info: dict = {}
    computed = False
    if masks is None and flows is not None and T > 1:
        masks, info = find_foreground(frames, flows, cfg)
        if cfg.detector:  # a local Mask R-CNN's instances where they lie in the motion masks
            masks, picked = detector_masks(frames, masks, cfg, progress)
            info.update(picked, coverage_after_detector=float(masks.mean()))
        computed = True
    fw = flows["fw"].astype(np.float32) if flows is not None and T > 1 else None
    fw_ok = flows.get("fw_ok") if flows is not None else None
    if masks is None:
        h0, desc = foreground_mappings(h, w, np.zeros((T, h, w), np.float32), margin=cfg.margin, how="identity")
    else:
        h0, desc = foreground_mappings(h, w, masks, fw, fw_ok, margin=cfg.margin, how=cfg.foreground)
    return {"h0": h0, "masks": masks, "computed": computed, "how": desc, "info": info}
