"""Measure what the model for one clip needs to know: the analysis's numbers, from which
:mod:`layercam.engine.decide` (through :func:`layercam.engine.resolve.resolve`, once per run)
chooses the model's components.

Measures (:func:`measure`): exposure variation (from the spec), clipped fractions, global motion
(homography fit of the cached flow), independent motion (flow residual after the homography) and
relative blur between neighbouring frames (:mod:`layercam.vision.sharpness`, tile by tile). Motion and
blur are measured only on what both frames of a pair see well (:mod:`layercam.core.visibility`): not
clipped, not in the noise floor, textured above the noise. Between frames several stops apart
the flow elsewhere is noise (a static, registered 3-shot bracket read "independent motion in all
pairs"), and noise, clipping and glare read as blur.
"""

from __future__ import annotations

import numpy as np

from layercam.core.visibility import at_floor, clipped
from layercam.vision.scale import ResizedFrames

# thresholds of the measures (each documented where it is used; the rules that decide from them:
# layercam.engine.decide)
IND_MOTION_PX = 1.5          # residual flow (px) beyond which a pixel moves on its own
IND_MOTION_FRAC = (0.02, 0.6)  # fraction of such pixels that makes a foreground (not noise, not all):
                             # camera shake puts flow errors on up to 1.4% of the pixels of a pair
                             # (synth shake, 96x96); an object moving on its own covered 9-15%
LONG_REACH = 8               # independent motion also measured between frames this many apart
                             # (layercam.vision.motion.long_range_moving_share):
                             # a slow object (DAVIS cows, 0.1-0.5 px per frame) in 0% of neighbour pairs
MIN_EVIDENCE = 0.03          # a pair counts for motion when both frames see well this share of its pixels
BLUR_SIGMA = 0.8             # relative blur (Gaussian sigma, px) of a tile that needs a blur generator
MIN_TILES = 3                # a pair with fewer comparable tiles says nothing about blur
MIN_TILE_FRACTION = 0.25     # ... nor one with under this fraction of the median pair's comparable tiles:
                             # 5 of 6 tiles of one pair of a sharp composite (37 elsewhere) chose a blur
                             # generator for an alternating-exposure video without blur
MAX_BLUR_PAIRS = 32          # pairs compared for blur, evenly spread over a long clip


def _motion(frames: np.ndarray, flow: dict, frame_hw: tuple[int, int]) -> tuple[dict, np.ndarray]:
    """Global and independent motion from the flow stage's arrays, on what both frames see well;
    also the pixels that move on their own ``(T-1, H, W)`` bool."""
    part, moving = _motion_part(frames, flow)
    return _motion_summary([part], flow["homs"], tuple(np.shape(flow["fw"])[1:3]), frame_hw), moving


def _motion_part(frames, flow: dict) -> tuple[dict, np.ndarray]:
    """What :func:`_motion_summary` needs of the consecutive pairs of ``flow`` (``fw``, ``fw_ok``,
    ``vis``, ``homs`` of these pairs; ``frames`` only without ``vis``)."""
    from layercam.vision.flow import residual_motion
    from layercam.core.visibility import pair_visible

    fw = np.asarray(flow["fw"]).astype(np.float32)
    ok = np.asarray(flow["fw_ok"])
    vis = np.asarray(flow["vis"]) if "vis" in flow else pair_visible(frames, fw)
    seen = vis & ok
    mag = np.sqrt((fw**2).sum(-1))
    share = seen.mean(axis=(1, 2))
    res = residual_motion(fw, np.asarray(flow["homs"])[: len(fw)])
    means = np.array([mag[t][seen[t]].mean() if seen[t].any() else 0.0 for t in range(len(fw))])
    moving = (res > IND_MOTION_PX + 0.05 * means[:, None, None]) & seen
    from layercam.vision.motion import long_range_moving_share

    # a share of the whole pair, as IND_MOTION_FRAC was measured
    return {"ok": float(ok.sum()), "pixels": ok.size, "share": share, "mag_seen": mag[seen],
            "frac": moving.mean(axis=(1, 2)),
            "long": long_range_moving_share(fw, seen, LONG_REACH, IND_MOTION_PX)}, moving
            # followed through what both frames see well


def _motion_summary(parts: list[dict], homs: np.ndarray, hw: tuple[int, int], frame_hw: tuple[int, int]) -> dict:
    """The motion measures over the pairs of ``parts`` (:func:`_motion_part` of one or more runs of
    consecutive pairs); the corner shift (frame pixels) from every pair's homography ``homs`` (on
    the flow's grid ``hw``)."""
    share = np.concatenate([p["share"] for p in parts])
    mag_seen = np.concatenate([p["mag_seen"] for p in parts])
    frac = np.concatenate([p["frac"] for p in parts])
    long_share = np.concatenate([p["long"] for p in parts])
    m = {
        "flow_consistent": float(sum(p["ok"] for p in parts) / max(sum(p["pixels"] for p in parts), 1)),
        "seen_well": float(share.mean()),
        "global_motion_px": float(np.median(mag_seen)) if mag_seen.size else 0.0,  # nothing seen: no evidence of motion
        "corner_shift_px": _corner_shift(homs, hw, frame_hw),
    }
    evidence = share >= MIN_EVIDENCE
    lo, hi = IND_MOTION_FRAC
    m["motion_pairs_measured"] = int(evidence.sum())
    m["independent_motion_frac"] = float(np.median(frac[evidence])) if evidence.any() else 0.0
    fg = ((frac > lo) & (frac < hi))[evidence]
    m["independent_pairs"] = float(fg.mean()) if evidence.any() else 0.0
    m["moving_pairs"] = int(fg.sum())
    fg_long = (long_share > lo) & (long_share < hi)
    m["independent_frac_long"] = float(np.median(long_share)) if len(long_share) else 0.0
    m["independent_pairs_long"] = float(fg_long.mean()) if len(long_share) else 0.0
    m["moving_pairs_long"] = int(fg_long.sum())
    return m


MOTION_PAIRS = 48   # a clip with more pairs than this has its motion measured on MOTION_WINDOWS runs of
MOTION_WINDOWS = 3  # consecutive pairs spread evenly over it (as many pairs in all): the analysis's memory
                    # and time are those of a 49-frame clip, whatever the clip's length


def motion_windows(pairs: int) -> list[tuple[int, int]]:
    """The runs ``[a, b)`` of consecutive pairs the motion is measured on: all of them for a clip of
    at most ``MOTION_PAIRS`` pairs, else ``MOTION_WINDOWS`` runs of ``MOTION_PAIRS // MOTION_WINDOWS``
    spread evenly from the first pair to the last.

    >>> motion_windows(47), motion_windows(767)
    ([(0, 47)], [(0, 16), (376, 392), (751, 767)])
    """
    if pairs <= MOTION_PAIRS:
        return [(0, pairs)]
    k = MOTION_PAIRS // MOTION_WINDOWS
    return [(int(a), int(a) + k) for a in np.linspace(0, pairs - k, MOTION_WINDOWS).round()]


def _corner_shift(homs: np.ndarray, hw: tuple[int, int], frame_hw: tuple[int, int]) -> float:
    """How far (frame pixels) the chained pair homographies (on the flow's grid ``hw``) move a
    frame corner from the middle frame's view: below ``STATIC_CORNER_PX`` the camera is static
    (:func:`layercam.engine.resolve.resolve`) and the bootstrap registers the frames by the identity."""
    from layercam.core.geometry import chain_homographies, max_corner_shift, middle_frame

    homs = np.asarray(homs, np.float64)
    return round(max_corner_shift(chain_homographies(homs, middle_frame(len(homs) + 1)), *hw) * frame_hw[0] / hw[0], 3)


def _blur(frames: np.ndarray, homs: np.ndarray | None, moving: np.ndarray | None, pairs=None) -> dict:
    """Relative blur between neighbours (:func:`layercam.vision.sharpness.pair_relative_blur`, leaving
    out the pixels that move on their own, ``moving (T-1, H, W)``: there the homography pairs
    different content): per pair the share of comparable tiles at least ``BLUR_SIGMA`` apart (a pair
    with fewer than ``MIN_TILES``, or than ``MIN_TILE_FRACTION`` of the median pair's, is not
    measured); the largest share, and the 90th percentile of the tiles' relative blur in that pair.
    ``pairs``: the pairs that may be compared (those ``moving`` holds; default all), at most
    ``MAX_BLUR_PAIRS`` of them evenly spread are."""
    from layercam.vision.sharpness import pair_relative_blur

    if pairs is None:
        pairs = np.arange(max(len(frames) - 1, 0))
    pairs = np.asarray(pairs, int)
    n = len(pairs)
    pairs = pairs[np.unique(np.linspace(0, n - 1, min(n, MAX_BLUR_PAIRS)).round().astype(int))] if n > 0 else []
    per_pair = [np.abs(pair_relative_blur(frames[t], frames[t + 1],
                                          None if homs is None else homs[t],
                                          None if moving is None else moving[t])) for t in pairs]
    counts = [len(x) for x in per_pair if len(x) >= MIN_TILES]
    enough = max(MIN_TILES, MIN_TILE_FRACTION * float(np.median(counts))) if counts else MIN_TILES
    shares, best, sigma = [], -1.0, 0.0
    for tiles in per_pair:
        if len(tiles) < enough:
            shares.append(None)
            continue
        sh = float((tiles >= BLUR_SIGMA).mean())
        shares.append(round(sh, 3))
        if sh > best:
            best, sigma = sh, float(np.percentile(tiles, 90))
    return {"blur_tile_share": shares, "max_blur_tile_share": max(best, 0.0),
            "max_blur_sigma": round(sigma, 3),
            "blur_pairs_measured": sum(v is not None for v in shares)}


def measure(clip, exposures, flow: dict | None) -> dict:
    """The numbers the decisions are made from. ``flow`` is the flow stage's arrays or None; the
    motion and blur are measured on the flow's grid (a working size for large frames,
    :data:`layercam.vision.scale.WORKING_SHORT_SIDE`: there distances are in its pixels; the corner shift is in frame
    pixels), on at most ``MOTION_PAIRS`` pairs (:func:`motion_windows`). Frames and flows are read a frame or
    a window at a time."""
    frames = clip.frames
    n = clip.T * clip.H * clip.W
    m: dict = {
        "frames": clip.T,
        "distinct_exposures": exposures.count_distinct,
        "exposure_range_ev": float(np.ptp(exposures.log2_dt)) if exposures.T else 0.0,
        "clipped_high": sum(int(clipped(f).any(-1).sum()) for f in frames) / n,  # a frame at a time
        "clipped_low": sum(int(at_floor(f).all(-1).sum()) for f in frames) / n,
    }
    if flow is None or "fw" not in flow or len(flow["fw"]) == 0:
        m.update(global_motion_px=0.0, independent_motion_frac=0.0, independent_pairs=0.0,
                 moving_pairs=0, flow_consistent=1.0, motion_pairs_measured=0)
        m.update(_blur(frames, None, None))
        return m
    work = tuple(flow["fw"].shape[1:3])
    small = ResizedFrames(frames, work)
    parts, moving = [], {}
    for a, b in motion_windows(len(flow["fw"])):
        win = {k: flow[k][a:b] for k in ("fw", "fw_ok", "vis") if k in flow}
        win["homs"] = np.asarray(flow["homs"])[a:b]
        fr = np.stack([small[t] for t in range(a, b + 1)]) if "vis" not in flow else None
        part, mov = _motion_part(fr, win)
        parts.append(part)
        moving.update({a + i: mov[i] for i in range(b - a)})
    m.update(_motion_summary(parts, flow["homs"], work, (clip.H, clip.W)))
    m.update(_blur(small, flow["homs"], moving, sorted(moving)))
    return m
