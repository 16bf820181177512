"""Decide what the model for one clip contains: measure the clip, then choose. Every decision
carries its measured reason and is written into the config's ``model`` section (and the blur
generator's shape); a value set there (a flag such as ``--layers 2``, or ``--set``) is kept.

Measures (:func:`measure`): exposure variation (from the spec), clipped fractions, global motion
(homography fit of the cached flow), independent motion (flow residual after the homography) and
relative blur between neighbouring frames (:mod:`layercam.vision.sharpness`, tile by tile). Motion and
blur are measured only on what both frames of a pair see well (:mod:`layercam.core.visibility`): not
clipped, not in the noise floor, textured above the noise. Between frames several stops apart
the flow elsewhere is noise (a static, registered 3-shot bracket read "independent motion in all
pairs"), and noise, clipping and glare read as blur.
"""

from __future__ import annotations

import math

import numpy as np

from layercam.core.config import AUTO, Config
from layercam.core.geometry import STATIC_CORNER_PX
from layercam.core.visibility import at_floor, clipped
from layercam.vision.scale import ResizedFrames

# thresholds of the rules (each documented where it is used)
IND_MOTION_PX = 1.5          # residual flow (px) beyond which a pixel moves on its own
IND_MOTION_FRAC = (0.02, 0.6)  # fraction of such pixels that makes a foreground (not noise, not all):
                             # camera shake puts flow errors on up to 1.4% of the pixels of a pair
                             # (synth shake, 96x96); an object moving on its own covered 9-15%
IND_MOTION_PAIRS = 0.3       # ... in at least this fraction of neighbour pairs
MIN_MOVING_PAIRS = 2         # ... and in at least this many: one pair can be a flow failure (e.g. between
                             # two differently defocused images; docs/measurements.md)
LONG_REACH = 8               # ... or of pairs this many frames apart (layercam.vision.motion.long_range_moving_share):
                             # a slow object (DAVIS cows, 0.1-0.5 px per frame) in 0% of neighbour pairs
LONG_MIN_PAIRS = 2           # ... at least two of them
MIN_EVIDENCE = 0.03          # a pair counts for motion when both frames see well this share of its pixels
STATIC_PX = 0.3              # below this median flow the scene is static: no flow loss needed
ROBUST_STACK = 0.05          # loss.robust=auto for fuse-stack without a blur generator: the colour error's
                             # Cauchy scale (pixel value). A bracket's shots come from different moments,
                             # and under MSE the shared tone curve bent to fit where the scene changed
                             # between them (NTIRE 000001); with a blur generator (a focus stack) the PSFs
                             # are fitted by the large errors at edges, so MSE. docs/measurements.md
FLOOR_GRID_LEVELS = 6        # a clip whose training the step cap shortens (a short stack: few looks at each
                             # scene point) gets at most this many atlas grid levels (`quality` has 8):
                             # more scales between the same coarsest and finest fitted its few shots'
                             # disagreements. docs/measurements.md
MIN_STEPS = 300              # the step cap's floor: a clip the cap gives fewer steps trains this many (and FLOOR)
MIN_SAMPLES = 2_457_600      # ... with a blur generator, the floor in pixels sampled (fast's 600 steps x 4096) in the
                             # preset's model and batch: its PSFs learn after a warm-up
FLOOR = {"scene.grid_levels": FLOOR_GRID_LEVELS, "scene.atlas_width": 64, "train.batch": 4096}
                             # ... and one the cap puts at its floor (MIN_STEPS; a 3-shot stack of
                             # up to ~300x300 px) trains this model whatever the preset (the batch at most
                             # this): on the NTIRE crops and twelve taipei crops no preset's difference
                             # there was larger than the spread of three seeds, larger batches learned a
                             # softer tone shoulder and more steps fitted the shots' noise. Not with a
                             # blur generator (MIN_SAMPLES). docs/measurements.md
BLUR_SIGMA = 0.8             # relative blur (Gaussian sigma, px) of a tile that needs a blur generator
BLUR_TILE_SHARE = 0.4        # ... on at least this share of the tiles of some pair (both signs: focus
                             # that differs by region; the real captures' shares: docs/measurements.md)
MIN_TILES = 3                # a pair with fewer comparable tiles says nothing about blur
MIN_TILE_FRACTION = 0.25     # ... nor one with under this fraction of the median pair's comparable tiles:
                             # 5 of 6 tiles of one pair of a sharp composite (37 elsewhere) chose a blur
                             # generator for an alternating-exposure video without blur
BLUR_PAIR_SHARE = 0.25       # ... in more than this share of the pairs measured (a clip of two frames: its
                             # pair): a share, not a count, so that a long clip's stray pairs do not add
                             # up to a blur generator (docs/measurements.md, 2026-11-28)
MAX_BLUR_PAIRS = 32          # pairs compared for blur, evenly spread over a long clip
OFFSET_PER_SIGMA = 5.0       # max offset (px) per px of relative blur: the energy match underestimates
                             # motion and disc blur (8 px shake reads as sigma ~0.9; s = 5 in the paper)


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

    return {"ok": float(ok.sum()), "pixels": ok.size, "share": share, "mag_seen": mag[seen], "frac": moving.mean(axis=(1, 2)),  # a share of the whole pair, as IND_MOTION_FRAC was measured
            "long": long_range_moving_share(fw, seen, LONG_REACH, IND_MOTION_PX)}, moving  # followed through what both frames see well


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
    per_pair = [np.abs(pair_relative_blur(frames[t], frames[t + 1], None if homs is None else homs[t], None if moving is None else moving[t])) for t in pairs]
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
    return {"blur_tile_share": shares, "max_blur_tile_share": max(best, 0.0), "max_blur_sigma": round(sigma, 3), "blur_pairs_measured": sum(v is not None for v in shares)}


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
        m.update(global_motion_px=0.0, independent_motion_frac=0.0, independent_pairs=0.0, moving_pairs=0, flow_consistent=1.0, motion_pairs_measured=0)
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


def unfound_foreground(cfg: Config, foreground: dict | None) -> str | None:
    """Why a two-layer run found no foreground, when the analysis chose its two layers (``cfg``:
    the settings as given, ``model.layers`` auto) and the foreground finder's verdict
    (:mod:`layercam.vision.segment.verdict`; ``foreground``: the bootstrap's account of its
    foreground, ``masks`` and ``verdict``, None for one layer) is that its masks hold no consistent,
    independently moving object; None otherwise (one layer, layers given, masks given, an object
    found). The task then decides again with ``measures["foreground_found"] = False`` (one layer,
    this reason)."""
    fg = foreground or {}
    verdict = fg.get("verdict") or {}
    if cfg.model.layers != AUTO or fg.get("masks") != "motion segmentation" or verdict.get("found", True):
        return None
    return verdict.get("reason") or "the foreground finder found none"


MODEL_KEYS = ("layers", "tone_mapper", "exposures", "blur", "max_offset", "flow_loss")  # what the analysis reports


def decide(cfg: Config, clip, exposures, task: str, measures: dict | None = None) -> tuple[Config, dict]:
    """The analysis's choices written into a copy of ``cfg``: each ``auto`` of the ``model`` section
    (layers, tone mapper, exposures, blur generator, flow loss) and the blur generator's
    ``max_offset``; returns ``(cfg, reasons)``, one measured reason per choice. A value that is
    not ``auto`` (a flag such as ``--layers 2``, or ``--set``) is kept and its reason says so.
    Without ``measures`` (no flow yet) only the exposure-based choices are informed.
    """
    cfg = cfg.copy()
    m, b = cfg.model, cfg.blur
    mm = measures or {}
    r: dict = {}

    def forced(key: str, value) -> bool:
        if value == AUTO:
            return False
        r[key.split(".")[1]] = f"forced ({key}={value})"
        return True

    # layers: a second layer only when something moves against the camera's global motion
    pairs = mm.get("independent_pairs", 0.0)
    frac = mm.get("independent_motion_frac", 0.0)
    pairs_long = mm.get("independent_pairs_long", 0.0)
    if not forced("model.layers", m.layers):
        if mm.get("masks_given"):
            m.layers, r["layers"] = 2, "foreground masks given (--masks)"
        elif mm.get("foreground_found") is False:  # two layers were chosen, and the finder found no object (unfound_foreground)
            m.layers, r["layers"] = 1, f"no consistent independently moving object: {mm.get('foreground_reason', '')}"
        elif clip.T > 1 and pairs >= IND_MOTION_PAIRS and mm.get("moving_pairs", 0) >= MIN_MOVING_PAIRS:
            m.layers = 2
            r["layers"] = f"independent motion in {pairs:.0%} of frame pairs (median {frac:.1%} of pixels beyond {IND_MOTION_PX} px of the global homography)"
        elif clip.T > 1 and pairs_long >= IND_MOTION_PAIRS and mm.get("moving_pairs_long", 0) >= LONG_MIN_PAIRS:
            m.layers = 2
            r["layers"] = f"independent motion in {pairs_long:.0%} of frame pairs {LONG_REACH} frames apart (median {mm.get('independent_frac_long', 0.0):.1%} of pixels beyond {IND_MOTION_PX} px of the static scene)"
        else:
            m.layers = 1
            if not measures:
                r["layers"] = "one layer (no flow measured)"
            elif mm.get("motion_pairs_measured", 1) == 0:
                r["layers"] = f"no pair of frames sees {MIN_EVIDENCE:.0%} of its pixels well in both frames: no evidence of independent motion"
            elif pairs >= IND_MOTION_PAIRS:
                r["layers"] = f"independent motion in only {mm.get('moving_pairs', 0)} pair(s) of frames (< {MIN_MOVING_PAIRS}): taken as a flow failure"
            else:
                r["layers"] = f"no independent motion (in {pairs:.0%} of the pairs measured, on the pixels both frames see well)"

    # tone mapper: a response curve is only identifiable from more than one exposure
    n_exp = exposures.count_distinct
    learned = exposures.learn != "none"
    if not forced("model.tone_mapper", m.tone_mapper):
        if n_exp > 1 or learned:
            m.tone_mapper = "learned"
            r["tone_mapper"] = f"{n_exp} distinct exposures" + (" (learned)" if learned else "")
        else:
            m.tone_mapper = "fixed"
            r["tone_mapper"] = "one exposure: no response curve can be learned, sRGB assumed"
    if m.exposures == "learned" and not learned:
        m.exposures, r["exposures"] = "given", "exposures were given; nothing to learn"
    elif not forced("model.exposures", m.exposures):
        m.exposures, r["exposures"] = ("learned" if learned else "given"), exposures.reason

    # blur: some pair of frames differs in sharpness on a good share of what both see well
    share = mm.get("max_blur_tile_share", 0.0)
    sigma = mm.get("max_blur_sigma", 0.0)
    shares = [v for v in mm.get("blur_tile_share", []) if v is not None]
    over = sum(v >= BLUR_TILE_SHARE for v in shares)  # pairs that differ
    measured = bool(measures) and over > BLUR_PAIR_SHARE * len(shares)
    if not forced("model.blur", m.blur):
        if measured:
            m.blur = "on"
            r["blur"] = f"sharpness differs by at least {BLUR_SIGMA} px (Gaussian sigma) on at least {BLUR_TILE_SHARE:.0%} of the tiles in {over} of {len(shares)} pairs measured (up to {share:.0%}, 90th percentile {sigma:.1f} px)"
        else:
            m.blur = "off"
            if not measures:
                r["blur"] = "no blur expected (nothing measured)"
            elif over:  # some pairs differ, too few of them
                r["blur"] = f"sharpness differs by {BLUR_SIGMA} px on at least {BLUR_TILE_SHARE:.0%} of the tiles in only {over} of {len(shares)} pairs measured (more than {BLUR_PAIR_SHARE:.0%} needed): not the camera"
            elif mm.get("blur_pairs_measured", 0) == 0:
                r["blur"] = "no pair of frames has enough texture that both see well to compare sharpness"
            else:
                why = "exposure, not focus" if n_exp > 1 else "the frames are equally sharp"
                r["blur"] = f"sharpness differs by {BLUR_SIGMA} px on at most {share:.0%} of the tiles of a pair (< {BLUR_TILE_SHARE:.0%}): {why}"
            if task == "deblur-video" and measures:  # the user asked for sharper frames: say why there are none
                r["blur"] += "; a frame is sharpened from sharper views of the same place, so the frames come out as sharp as they went in (--blur 3x3 forces the blur generator)"
    if cfg.loss.robust == AUTO:  # an exposure bracket (a stack without a blur generator to fit by its edges)
        cfg.loss.robust = ROBUST_STACK if task == "fuse-stack" and m.blur == "off" else 0.0
    if not forced("blur.max_offset", b.max_offset):
        if m.blur == "off":
            b.max_offset, r["max_offset"] = 5.0, "unused (blur off)"
        elif measured:
            b.max_offset = float(min(max(math.ceil(OFFSET_PER_SIGMA * sigma), 2.0), 8.0))
            r["max_offset"] = f"{OFFSET_PER_SIGMA:g} x the relative blur, {b.max_offset:.0f} px"
        else:
            b.max_offset, r["max_offset"] = 5.0, "default (nothing measured)"

    # flow loss: only helps when things move
    motion = mm.get("global_motion_px", 0.0)
    if not forced("model.flow_loss", m.flow_loss):
        if clip.T < 2:
            m.flow_loss, r["flow_loss"] = False, "a single frame has no neighbours"
        elif measures and m.layers == 1 and (motion < STATIC_PX or mm.get("corner_shift_px", 1e9) < STATIC_CORNER_PX):
            m.flow_loss = False
            r["flow_loss"] = f"static scene (median flow {motion:.2f} px on what both frames see well; the pair homographies move a corner {mm.get('corner_shift_px', 0.0):.2f} px)"
        else:
            m.flow_loss = True
            r["flow_loss"] = f"median flow {motion:.2f} px" if measures else "more than one frame"
    return cfg, r


def model_summary(cfg: Config) -> dict:
    """The decided model as the report and the analysis table show it: ``{"layers": 1, "blur":
    "3x3" | "off", "max_offset": 5.0, ...}``."""
    m, b = cfg.model, cfg.blur
    return {"layers": m.layers, "tone_mapper": m.tone_mapper, "exposures": m.exposures, "blur": "off" if m.blur == "off" else f"{b.n}x{b.n}", "max_offset": b.max_offset, "flow_loss": m.flow_loss}


def has_floor_model(cfg: Config) -> bool:
    """Whether a clip ``cfg`` trains at the step cap's floor gets :data:`FLOOR`'s model: grid
    atlases without a blur generator (the floor was measured there; a blur generator keeps
    :data:`MIN_SAMPLES`, and `paper`'s positional encoding its own width and batch)."""
    return cfg.model.blur != "on" and cfg.scene.encoding == "grid"


def step_cap(train, frames: int, pixels: int, blur: bool = False) -> int:
    """The most steps ``train`` (a :class:`layercam.core.config.TrainConfig`) may take on a clip of
    ``frames`` frames of ``pixels`` pixels each: ``passes_per_frame * frames`` passes over its
    ``frames * pixels`` pixels in batches of ``train.batch``, but never fewer than :data:`MIN_STEPS`
    (the floor, where :func:`layercam.engine.resolve.resolve` also sets :data:`FLOOR`), or with a ``blur``
    generator never fewer pixels sampled than :data:`MIN_SAMPLES`; ``passes_per_frame = 0``:
    ``train.steps``.

    >>> from layercam.core.config import TrainConfig
    >>> step_cap(TrainConfig(steps=2000, batch=8192), 3, 256 * 256)  # a 3-shot bracket: the floor
    300
    >>> step_cap(TrainConfig(steps=2000, batch=8192), 3, 768 * 510)  # 6 passes over a larger one
    861
    >>> step_cap(TrainConfig(steps=6000, batch=16384), 48, 256 * 144)  # a 48-frame clip: not capped
    6000
    >>> step_cap(TrainConfig(steps=600, batch=4096), 4, 32 * 32)  # a tiny clip: the floor
    300
    >>> step_cap(TrainConfig(steps=2000, batch=8192), 3, 256 * 256, blur=True)  # a focus stack: MIN_SAMPLES
    300
    >>> step_cap(TrainConfig(steps=600, batch=4096), 4, 32 * 32, blur=True)
    600
    """
    if train.passes_per_frame <= 0:
        return int(train.steps)
    need = math.ceil(train.passes_per_frame * frames * frames * pixels / train.batch)
    floor = math.ceil(MIN_SAMPLES / train.batch) if blur else MIN_STEPS
    return int(min(train.steps, max(need, floor, 1)))
