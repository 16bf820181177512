"""The model a clip needs, chosen from what the analysis measured (:func:`layercam.vision.analyse.measure`):
every ``auto`` of the ``model`` section (layers, tone mapper, exposures, blur generator, flow loss),
the blur generator's reach and the colour loss's scale, each with its measured reason; a value set
there (a flag such as ``--layers 2``, or ``--set``) is kept. The rules of
:func:`layercam.engine.resolve.resolve`, which alone calls them (once per run).
"""

from __future__ import annotations

import math

from layercam.core.config import AUTO, Config
from layercam.core.geometry import STATIC_CORNER_PX
from layercam.vision.analyse import BLUR_SIGMA, IND_MOTION_PX, LONG_REACH, MIN_EVIDENCE

# thresholds of the rules (each documented where it is used; the measures': layercam.vision.analyse)
IND_MOTION_PAIRS = 0.3       # two layers: independent motion (analyse.IND_MOTION_FRAC) in at least
                             # this fraction of neighbour pairs
MIN_MOVING_PAIRS = 2         # ... and in at least this many: one pair can be a flow failure (e.g. between
                             # two differently defocused images; docs/measurements.md)
LONG_MIN_PAIRS = 2           # ... or in at least this many pairs analyse.LONG_REACH frames apart
STATIC_PX = 0.3              # below this median flow the scene is static: no flow loss needed
ROBUST_STACK = 0.05          # loss.robust=auto for fuse-stack without a blur generator: the colour error's
                             # Cauchy scale (pixel value). A bracket's shots come from different moments,
                             # and under MSE the shared tone curve bent to fit where the scene changed
                             # between them (NTIRE 000001); with a blur generator (a focus stack) the PSFs
                             # are fitted by the large errors at edges, so MSE. docs/measurements.md
BLUR_TILE_SHARE = 0.4        # a blur generator: relative blur of analyse.BLUR_SIGMA on at least
                             # this share of the tiles of a pair (both signs: focus
                             # that differs by region; the real captures' shares: docs/measurements.md)
BLUR_PAIR_SHARE = 0.25       # ... in more than this share of the pairs measured (a clip of two frames: its
                             # pair): a share, not a count, so that a long clip's stray pairs do not add
                             # up to a blur generator (docs/measurements.md, 2026-11-28)
OFFSET_PER_SIGMA = 5.0       # max offset (px) per px of relative blur: the energy match underestimates
                             # motion and disc blur (8 px shake reads as sigma ~0.9; s = 5 in the paper)


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
        elif mm.get("foreground_found") is False:  # two layers were chosen, and the finder found no
                                                   # object (unfound_foreground)
            m.layers, r["layers"] = 1, f"no consistent independently moving object: {mm.get('foreground_reason', '')}"
        elif clip.T > 1 and pairs >= IND_MOTION_PAIRS and mm.get("moving_pairs", 0) >= MIN_MOVING_PAIRS:
            m.layers = 2
            r["layers"] = (f"independent motion in {pairs:.0%} of frame pairs (median {frac:.1%} "
                           f"of pixels beyond {IND_MOTION_PX} px of the global homography)")
        elif clip.T > 1 and pairs_long >= IND_MOTION_PAIRS and mm.get("moving_pairs_long", 0) >= LONG_MIN_PAIRS:
            m.layers = 2
            r["layers"] = (f"independent motion in {pairs_long:.0%} of frame pairs {LONG_REACH} "
                           f"frames apart (median {mm.get('independent_frac_long', 0.0):.1%} of "
                           f"pixels beyond {IND_MOTION_PX} px of the static scene)")
        else:
            m.layers = 1
            if not measures:
                r["layers"] = "one layer (no flow measured)"
            elif mm.get("motion_pairs_measured", 1) == 0:
                r["layers"] = (f"no pair of frames sees {MIN_EVIDENCE:.0%} of its pixels well in "
                               "both frames: no evidence of independent motion")
            elif pairs >= IND_MOTION_PAIRS:
                r["layers"] = (f"independent motion in only {mm.get('moving_pairs', 0)} pair(s) of "
                               f"frames (< {MIN_MOVING_PAIRS}): taken as a flow failure")
            else:
                r["layers"] = (f"no independent motion (in {pairs:.0%} of the pairs measured, on "
                               "the pixels both frames see well)")

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
            r["blur"] = (f"sharpness differs by at least {BLUR_SIGMA} px (Gaussian sigma) on at "
                         f"least {BLUR_TILE_SHARE:.0%} of the tiles in {over} of {len(shares)} "
                         f"pairs measured (up to {share:.0%}, 90th percentile {sigma:.1f} px)")
        else:
            m.blur = "off"
            if not measures:
                r["blur"] = "no blur expected (nothing measured)"
            elif over:  # some pairs differ, too few of them
                r["blur"] = (f"sharpness differs by {BLUR_SIGMA} px on at least "
                             f"{BLUR_TILE_SHARE:.0%} of the tiles in only {over} of {len(shares)} "
                             f"pairs measured (more than {BLUR_PAIR_SHARE:.0%} needed): not the "
                             "camera")
            elif mm.get("blur_pairs_measured", 0) == 0:
                r["blur"] = "no pair of frames has enough texture that both see well to compare sharpness"
            else:
                why = "exposure, not focus" if n_exp > 1 else "the frames are equally sharp"
                r["blur"] = (f"sharpness differs by {BLUR_SIGMA} px on at most {share:.0%} of the "
                             f"tiles of a pair (< {BLUR_TILE_SHARE:.0%}): {why}")
            if task == "deblur-video" and measures:  # the user asked for sharper frames: say why there are none
                r["blur"] += ("; a frame is sharpened from sharper views of the same place, so the "
                              "frames come out as sharp as they went in (--blur 3x3 forces the "
                              "blur generator)")
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
            r["flow_loss"] = (f"static scene (median flow {motion:.2f} px on what both frames see "
                              "well; the pair homographies move a corner "
                              f"{mm.get('corner_shift_px', 0.0):.2f} px)")
        else:
            m.flow_loss = True
            r["flow_loss"] = f"median flow {motion:.2f} px" if measures else "more than one frame"
    return cfg, r


def model_summary(cfg: Config) -> dict:
    """The decided model as the report and the analysis table show it: ``{"layers": 1, "blur":
    "3x3" | "off", "max_offset": 5.0, ...}``."""
    m, b = cfg.model, cfg.blur
    return {"layers": m.layers, "tone_mapper": m.tone_mapper, "exposures": m.exposures,
            "blur": "off" if m.blur == "off" else f"{b.n}x{b.n}", "max_offset": b.max_offset,
            "flow_loss": m.flow_loss}
