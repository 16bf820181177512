"""Step 3: the motion masks: the evidence (:mod:`layercam.vision.segment.evidence`) voted with its
neighbours along the flow, rid of parts that lie where the frame has no texture the flow can
follow, cleaned to one object per frame, and frames where the object stood still filled from
the nearest frame that holds it at its typical size (``clean.fill_still_frames``).

A frame's evidence counts where at least half of its pairs moved (``EVIDENCE``); it is averaged
with that of ``WINDOW`` neighbours on each side brought into its view along the flow, and a pixel is
foreground where the average reaches ``VOTE``, and only where the frame has texture the flow can
follow (:func:`layercam.core.visibility.textured`): flow over a smooth sky or road is interpolated from
its edges (the object's motion spills onto the road beside it), not measured. The object's own
smooth parts come back by their colours (:mod:`layercam.vision.segment.colour`). Where the largest
moving part is a dynamic texture (a stream, ripples: its outline keeps its place in the scene
though the flow inside it moves), the masks follow the one track of parts whose outline travels
with its flow, and otherwise the track of the largest area, not the largest part of each frame
(:mod:`layercam.vision.segment.dynamic`).
"""

from __future__ import annotations

import numpy as np

from layercam.core.errors import LayercamError
from layercam.vision.segment.clean import clean_mask, fill_still_frames, keep_object, mask_parts, warp_mask

EVIDENCE = 0.5       # a pixel moved in this share of its pairs
WINDOW = 2           # neighbours on each side that vote
VOTE = 0.4           # the voted share that makes a pixel foreground
TEXTURE = 0.006      # visibility.textured's threshold and window (a share of the short side)
TEXTURE_WINDOW = 0.0125


def check_flows(fw, bw) -> tuple[np.ndarray, np.ndarray]:
    f = np.asarray(fw, dtype=np.float32)
    b = np.asarray(bw, dtype=np.float32)
    if f.ndim != 4 or f.shape[-1] != 2 or b.shape != f.shape:
        raise LayercamError("motion segmentation needs forward and backward flows (T-1,H,W,2), "
                            f"got {f.shape} and {b.shape}")
    if f.shape[0] < 1:
        raise LayercamError("motion segmentation needs at least two frames")
    return f, b


def flow_checks(f: np.ndarray, b: np.ndarray, fw_ok=None, bw_ok=None) -> tuple[np.ndarray, np.ndarray]:
    """The flows' forward-backward checks ``(T-1, H, W)`` bool: the given ones, else computed."""
    from layercam.vision.flow import flow_consistency

    fo = flow_consistency(f, b) if fw_ok is None else np.asarray(fw_ok, bool)
    bo = flow_consistency(b, f) if bw_ok is None else np.asarray(bw_ok, bool)
    return fo, bo


def temporal_vote(ev: np.ndarray, fw: np.ndarray, bw: np.ndarray, window: int) -> np.ndarray:
    """Average of each frame's evidence with its neighbours' (up to ``window`` each side), brought
    into its view along the chained flow. ``(T, H, W)`` float in [0, 1]."""
    T = ev.shape[0]
    acc = ev.astype(np.float32).copy()
    cnt = np.ones(T, np.float32)
    for t in range(T):
        for k in range(1, window + 1):
            if t + k >= T:
                break
            m = ev[t + k].astype(np.float32)
            for j in range(t + k - 1, t - 1, -1):
                m = warp_mask(m, fw[j])
            acc[t] += m
            cnt[t] += 1
        for k in range(1, window + 1):
            if t - k < 0:
                break
            m = ev[t - k].astype(np.float32)
            for j in range(t - k, t):
                m = warp_mask(m, bw[j])
            acc[t] += m
            cnt[t] += 1
    return acc / cnt[:, None, None]


def motion_masks(fw, bw, fw_ok=None, bw_ok=None, *, cfg, frames=None, homs=None) -> tuple[np.ndarray, dict]:
    """Foreground masks of whatever moves on its own: ``(T, H, W)`` float32 in {0, 1}, and an info
    dict (coverage per frame, frames filled from neighbours, and ``evidence``: the motion evidence
    ``(T, H, W)`` the masks came from). With the camera's ``homs`` ``(T-1, 3, 3)`` (frame t -> t+1),
    a clip whose largest moving parts do not travel with their own flow
    (:func:`layercam.vision.segment.dynamic.keeps_place`;
    ``info["travel_p"]``) takes the track of parts that travels instead, where one does, and any
    other the track of the largest area (:func:`layercam.vision.segment.dynamic.follow`). ``fw_ok``,
    ``bw_ok`` ``(T-1, H, W)``: the flows'
    forward-backward checks (computed when None); ``cfg``: a :class:`layercam.core.config.SegmentConfig`
    (``reach``, ``k_sigma``). With the ``frames`` ``(T, H, W[, C])``, evidence counts only where
    the frame has texture."""
    from layercam.vision.segment.evidence import motion_evidence
    from layercam.core.visibility import textured

    f, b = check_flows(fw, bw)
    fo, bo = flow_checks(f, b, fw_ok, bw_ok)
    soft, info = motion_evidence(f, b, fo, bo, cfg.reach, cfg.k_sigma)
    tex = None
    if frames is not None:
        tex = textured(frames, TEXTURE, TEXTURE_WINDOW)
        if tex.shape != soft.shape:
            raise LayercamError(f"motion segmentation: frames {tex.shape} do not match the flows {soft.shape}")
        info["untextured"] = round(float(1 - tex.mean()), 4)
    raw = temporal_vote(soft >= EVIDENCE, f, b, WINDOW) >= VOTE
    if tex is not None:
        raw &= tex
    parts = [mask_parts(m) for m in raw]  # cut once: the largest part of each, and the tracks, choose among them
    masks = [keep_object(p) for p in parts]
    if homs is not None:
        from layercam.vision.segment.dynamic import follow, keeps_place, travel

        moves = travel(raw, f, b, fo, bo, homs, cfg.reach)
        keeps, info["travel_p"] = keeps_place(masks, moves)
        # one object over the clip: where the largest parts are a dynamic texture, the track that travels
        followed = follow(parts, moves if keeps else raw, b)
        if followed is not None:
            masks = list(followed)
    masks, filled = fill_still_frames(np.stack(masks), f, b)
    masks = np.stack([clean_mask(m) for m in masks]) if filled else masks
    cover = masks.reshape(len(masks), -1).mean(1)
    info.update(evidence=soft, coverage_mean=float(cover.mean()), coverage_min=float(cover.min()),
                coverage_max=float(cover.max()), filled_from_neighbours=filled,
                empty_frames=int((cover == 0).sum()))
    return masks.astype(np.float32), info
