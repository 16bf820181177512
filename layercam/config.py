"""Typed settings: one dataclass per section, presets as TOML files, ``--set section.key=value``.

Every field is typed (``int``, ``float``, ``bool``, ``str``, a ``Literal`` of choices, or a number
or ``"auto"``) and carries its range in :func:`setting`; a value is converted and checked when it is
set, and the whole config once more when it is loaded (:func:`load_config`) or a run starts, so a
bad preset value or ``--set`` fails with one line before any work. NaN and infinities are refused
everywhere.

A preset (``configs/<name>.toml``, shipped inside the package as ``layercam.configs``) holds only
the values that differ from the defaults below. ``load_config("fast", ["train.steps=500"])``
returns a :class:`Config`; ``Config.section_dict("train")`` is what a stage hashes for its cache key.

``"auto"`` values are decided per clip, once, by :func:`layercam.resolve.resolve` (from what the
analysis measures), which returns the run's frozen settings; sizes that follow from the clip (the atlas
grid's finest level, the alpha grid) are derived in code, and fixed sizes and weights are named
constants in the modules that use them. Each setting's comment says what it trades.

>>> cfg = load_config("fast", ["train.steps=50", "model.layers=2"])
>>> cfg.train.steps, cfg.model.layers, cfg.flow.method
(50, 2, 'dis_fast')
>>> load_config("fast", ["train.autocast=bogus"])
Traceback (most recent call last):
...
layercam.errors.LayercamError: train.autocast: expected one of auto, none, bf16, got 'bogus'
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import os
import re
import tomllib
import types
import typing
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Literal

from layercam.errors import LayercamError

AUTO = "auto"
INT_MAX = 2**31 - 1  # every integer setting fits a C int (OpenCV, torch's sizes and seeds): a larger one is refused


class Section:
    """Base of the settings' dataclasses: settable while a :class:`Config` is built (defaults,
    preset, ``--set``), frozen once resolved (:func:`freeze`; :mod:`layercam.resolve`)."""

    def __setattr__(self, name, value):
        if getattr(self, "_frozen", False):
            raise dataclasses.FrozenInstanceError(f"settings are resolved once (layercam.resolve): cannot set {getattr(self, '_name', '')}{name}")
        object.__setattr__(self, name, value)


def freeze(cfg: "Config") -> "Config":
    """``cfg`` made read-only, in place (each section and the config); returns it."""
    for sec in SECTIONS:
        obj = getattr(cfg, sec)
        object.__setattr__(obj, "_name", f"{sec}.")
        object.__setattr__(obj, "_frozen", True)
    object.__setattr__(cfg, "_frozen", True)
    return cfg


def setting(default: Any, lo: float | None = None, hi: float | None = None, *, above: float | None = None, below: float | None = None, check=None, keyed: bool = True) -> Any:
    """A dataclass field with a range: ``lo <= v <= hi``, ``v > above``, ``v < below`` (numbers;
    ``"auto"`` is not range-checked) and ``check(v) -> str | None`` (a message when wrong).
    ``keyed=False``: the setting cannot change a stage's result (how often to save), so it is left
    out of the cache keys (:meth:`Config.key_dict`)."""
    return field(default=default, metadata={"lo": lo, "hi": hi, "above": above, "below": below, "check": check, "keyed": keyed})


def _odd(v) -> str | None:
    return None if v == AUTO or v % 2 == 1 else "must be odd"


def _device(v: str) -> str | None:
    return None if re.fullmatch(r"auto|cpu|mps|cuda(:\d+)?", v) else "expected auto, cpu, cuda, cuda:N or mps"


def _lut(v: int) -> str | None:
    return None if v == 0 or v >= 2 else "must be 0 (off) or at least 2 knots"


@dataclass
class ModelConfig(Section):
    """What the model contains. ``auto``: decided for the clip by :func:`layercam.resolve.resolve`
    from what the analysis measured; anything else forces the choice (``--layers``, ``--blur``, ...)."""

    layers: Literal["auto", 1, 2] = AUTO              # 1: one atlas (static or rigid scene); 2: a foreground layer for an
                                                      # object moving on its own (an alpha field, twice the atlases)
    tone_mapper: Literal["auto", "learned", "fixed"] = AUTO  # learned CRF (needs exposures that differ) | the fixed sRGB curve
    exposures: Literal["auto", "given", "learned"] = AUTO  # learned where the exposure spec leaves them unknown
    blur: Literal["auto", "on", "off"] = AUTO           # the blur generator: sharp output from blurry frames, at 2-3 x the time
    flow_loss: bool | Literal["auto"] = AUTO            # flow consistency: keeps moving content registered; nothing to do on a static scene


@dataclass
class SceneConfig(Section):
    """Scene model: deformation, atlas and alpha fields of each layer (fixed sizes and constants:
    :mod:`layercam.scene.fields`)."""

    encoding: Literal["grid", "pe"] = "grid"  # atlas encoding: dense multi-resolution 2D grids (fast) | positional encoding
                                              # (the paper's PE(7) -> MLP: 1-2 orders of magnitude slower on a CPU)
    grid_levels: int = setting(6, 1, 16)     # grid levels between 16 cells and the atlas's extent: finer detail vs fitting
                                             # the frames' noise (quality: 8)
    atlas_width: int = setting(64, 1)        # atlas MLP width and depth: capacity vs time per step (paper: 512 x 4)
    atlas_depth: int = setting(2, 0)         # ... its hidden layers
    deformation: Literal["homography", "mlp"] = "homography"  # per-frame homography + bounded residual MLP (starts exact
                                             # from the flow) | one MLP of (x, y, t) (paper: fitted to its start first)
    deform_width: int = setting(64, 1)       # the deformation MLP's width and depth: non-rigid detail vs time (paper: 256 x 4)
    deform_depth: int = setting(2, 0)        # ... its hidden layers
    bootstrap: Literal["flow", "identity"] = "flow"  # the mappings' start: chained flow homographies | identity (paper)
    alpha_encoding: Literal["pe", "grid"] = "grid"  # alpha from a positional encoding alone (smooth outlines, the paper's)
                                             # | also dense (x, y, t) grids (thin parts; memory grows with the frames)


@dataclass
class ToneConfig(Section):
    """Tone mapper: three per-channel MLPs of log2 r' + log2 dt (paper: 2 layers of 128)."""

    width: int = setting(64, 1)      # each channel's MLP: width and depth (paper: 128 x 2); a wider curve fits more bends
    depth: int = setting(2, 0)       # ... its hidden layers
    lut: int = setting(1024, 0, check=_lut)  # the curves evaluated on this many knots and interpolated (error < 1e-4):
                                     # a step's tone mapping costs the knots, not the batch; 0: per pixel (paper)


@dataclass
class BlurConfig(Section):
    """Blur generator (paper Sec. 3.2): an n x n patch per pixel, offsets bounded by max_offset pixels
    (its nets' sizes and schedule: :mod:`layercam.camera.blur`)."""

    n: int | Literal["auto"] = setting(AUTO, 1, 15, check=_odd)  # patch side: larger reaches wider blur, costs n^2 scene
                                                                 # look-ups per pixel; auto: 5 past 2.5 px of blur, else 3
    max_offset: float | Literal["auto"] = setting(AUTO, 0.0, 64.0)  # s, px: how far the patch may spread; too little cannot
                                                                    # model the blur, too much lets it fit noise; auto: measured


@dataclass
class LossConfig(Section):
    """Loss terms whose weight a preset or a clip changes (the paper's fixed weights: :mod:`layercam.model`)."""

    robust: float | Literal["auto"] = setting(AUTO, 0.0, 1.0)  # colour error: 0 MSE (paper); c > 0 Cauchy
                                                 # c^2 ln(1 + (e / c)^2), errors past c (pixel value) count less: a bracket's
                                                 # shots that disagree bend the curve less, but edges fit less; auto: 0.05
                                                 # for fuse-stack without a blur generator, MSE elsewhere
    alpha_flow_keep: float = setting(0.25, 0.0, 1.0)  # two layers: share of the alpha flow weight kept once the flow has
                                                 # decayed (1: all through, as Kasten et al.): holds alpha on its object in a
                                                 # long fit, but a short fit (fast: 0) refines alpha better without it


@dataclass
class TrainConfig(Section):
    steps: int = setting(2000, 1)           # training steps: quality vs time (capped on short clips: passes_per_frame)
    bootstrap_steps: int = setting(200, 0)  # steps fitting the deformation to its start (paper: 10k)
    batch: int = setting(8192, 1)           # pixels per step: smoother gradients vs time and memory (paper: 30,000)
    lr: float = setting(5e-3, above=0.0, hi=1.0)  # Adam learning rate of the MLPs: speed vs stability (paper: 1e-4)
    grid_lr: float = setting(2e-2, above=0.0, hi=1.0)  # ... of the dense grid tables
    lr_decay: float = setting(0.1, 0.0, 1.0)  # final learning rate factor (cosine): 1 keeps it constant (paper)
    seed: int = setting(0, 0, 2**63 - 1)    # every random draw of training: the same seed, the same result
    autocast: Literal["auto", "none", "bf16"] = AUTO  # bf16 mixed precision: about 2x on a GPU, bf16's rounding in the
                                            # fields; auto: bf16 on a GPU that has it, fp32 elsewhere
    checkpoint_every: int = setting(500, 0, keyed=False)  # steps between checkpoints: work lost to a crash vs time spent saving
                                            # (0: only at the end and on Ctrl-C)
    device: str = setting("auto", check=_device)  # auto: CUDA when torch sees a GPU, else the CPU
    passes_per_frame: float = setting(2.0, 0.0)  # at most this many passes over the clip's pixels per frame of the clip:
                                            # more fit a short stack's noise and take time (0: no cap, the preset's steps;
                                            # paper: 0)


@dataclass
class FlowConfig(Section):
    method: Literal["dis_ultrafast", "dis_fast", "dis_medium", "raft", "raft_small", "raft_large"] = "dis_medium"  # OpenCV
                                            # DIS (no weights; faster is coarser) | torchvision RAFT from raft_weights ("raft":
                                            # the variant the file holds): finer on large motion, ~0.5-1.5 s a pair on a CPU
    raft_weights: str = ""                  # a local torchvision RAFT state dict for the raft methods (never downloaded)


@dataclass
class SegmentConfig(Section):
    """Motion segmentation of a two-layer clip (:func:`layercam.segment.motion_masks`) and the
    foreground layer's bootstrap. Distances in pixels of the clip being segmented.

    ``abs_px``: a residual below this (times sqrt(k) over k frames) is never motion. ``k_sigma``: a
    residual must also exceed the pair's robust residual level (median + k_sigma * 1.4826 MAD).
    ``reach``: pixels are followed along the flow to frames 1, 2, 4, ... up to ``reach`` away on
    each side (:func:`layercam.motion.long_range_evidence`); ``evidence``: the share of those pairs
    in which a pixel must move. ``f_vote``: the share of pairs that must vote for the epipolar model
    (parallax) for the clip to use it, and ``min_object``: the median share of a frame that its
    masks must still cover (otherwise it explained the object away as well). ``window``: neighbours
    on each side averaged along the flow; ``vote``: the averaged evidence that makes a pixel
    foreground. ``min_area``: components
    smaller than this fraction of the frame are dropped, and so are those smaller than
    ``keep_fraction`` of the frame's largest or farther from it than ``gap`` times its size (one
    object per frame). ``still_fraction``: a frame whose mask is smaller than
    this fraction of the clip's median area inherits its neighbours' masks (the object stood still).
    ``texture``: where a frame has texture the flow can follow
    (:func:`layercam.visibility.textured`: the structure tensor's smaller eigenvalue, in a Gaussian
    window of ``texture_window`` of the short side, over the local grey level; 0: off); a part of
    the voted evidence less than ``texture_share`` of which has texture is dropped.
    ``grabcut``: GrabCut iterations that tighten the masks to colour edges (0: off). ``background``:
    then each mask is corrected by the frame's residual against the background its neighbours show
    (:func:`layercam.segment.background_refine`; pixels in a ring of ``background_ring`` of the short
    side above ``background`` join, mask pixels within ``background_keep`` of it leave, judged by
    neighbours whose object overlaps this frame's by IoU under ``background_apart``; neighbours up
    to ``2 * background_reach`` frames away; 0: off; the residual that joins and drops pixels is
    the smallest over the background shifted by up to ``background_shift`` of the short side, so a
    post whose parallax the homography misses by a pixel matches it; 0: unshifted). ``colour``: then each mask is grown to the
    object's colours learned over the clip by a graph cut (:func:`layercam.segment.colour_cut`),
    within ``colour_reach`` times the object's size of it and only where the frame's relative
    residual against that background exceeds ``colour`` (0: off; it needs ``background``);
    ``colour_smooth``: the cut's weight on following colour edges; ``colour_distance``: its cost per
    object size a pixel lies away from the mask; ``colour_failure``: its weight on where the flow
    loses a pixel within 4 frames (:func:`layercam.motion.flow_failure`; 0: off); ``colour_clean``:
    the radii of the opening and closing that clean the cut (:func:`layercam.segment.clean_mask`),
    as a share of the other cleanings' (1% and 2% of the short side; 0.5 keeps legs and tails 1-3 px
    wide at 282x158; 1: the same radii; 0: neither). ``foreground``:
    the foreground layer's starting mapping, the object's own motion or the identity.
    ``margin``: the part of the foreground atlas the masked object fills at the start.
    ``refine``: fit the model once on the motion masks, take new masks from where each frame differs
    from its background layer near the fitted alpha (:func:`layercam.segment.refine_masks`, residual
    above ``refine_threshold`` in pixel values) and fit again on them: twice the training time.
    ``detector``: a local torchvision Mask R-CNN state dict (never downloaded); its instances scoring
    at least ``detector_score``, seen with the frame's short side at ``detector_size`` px, replace
    a frame's motion mask where at least ``detector_overlap`` of their area lies in it
    (:func:`layercam.detect.pick_instances`).
    """

    abs_px: float = setting(0.5, 0.0)
    k_sigma: float = setting(4.0, 0.0)
    reach: int = setting(8, 1, 64)
    evidence: float = setting(0.5, 0.0, 1.0)
    f_vote: float = setting(0.5, 0.0, 1.0)
    min_object: float = setting(0.005, 0.0, 1.0)
    window: int = setting(2, 0, 16)
    vote: float = setting(0.4, 0.0, 1.0)
    texture: float = setting(0.006, 0.0)
    texture_window: float = setting(0.0125, above=0.0, hi=1.0)
    texture_share: float = setting(0.5, 0.0, 1.0)
    min_area: float = setting(0.002, 0.0, 1.0)
    keep_fraction: float = setting(0.15, 0.0, 1.0)
    gap: float = setting(0.25, 0.0)
    still_fraction: float = setting(0.3, 0.0, 1.0)
    grabcut: int = setting(4, 0, 32)
    background: float = setting(0.15, 0.0, 1.0)
    background_keep: float = setting(0.075, 0.0, 1.0)
    background_apart: float = setting(0.5, 0.0, 1.0)
    background_reach: int = setting(4, 1, 32)
    background_ring: float = setting(0.05, 0.0, 1.0)
    background_shift: float = setting(0.0, 0.0, 0.05)
    colour: float = setting(0.3, 0.0)
    colour_reach: float = setting(2.0, above=0.0)
    colour_smooth: float = setting(2.0, 0.0)
    colour_distance: float = setting(1.0, 0.0)
    colour_failure: float = setting(1.0, 0.0)
    colour_clean: float = setting(0.5, 0.0, 1.0)  # 1 until 2026-11-25: DAVIS at balanced, libby 0.610 -> 0.635; the real suite within its spread (docs/layers/ceiling/)
    foreground: Literal["object", "identity"] = "object"
    margin: float = setting(0.6, above=0.0, hi=1.0)
    refine: bool = False
    refine_threshold: float = setting(0.1, above=0.0, hi=1.0)
    detector: str = ""                       # a torchvision Mask R-CNN weights file (layercam.detect); "": the motion masks alone
    detector_score: float = setting(0.5, 0.0, 1.0)
    detector_overlap: float = setting(0.3, above=0.0, hi=1.0)
    detector_size: int = setting(800, 64, 4096)


@dataclass
class ExportConfig(Section):
    half: bool = True                       # EXR half floats: half the disk, 3e-4 relative error
    reference: int | Literal["middle", "first", "last"] = "middle"  # fuse-stack: the view fused into (an index may be negative)
    faithful: bool = True                   # each frame's HDR agrees with the frame where it saw well (layercam/faithful.py):
                                            # the frame's own detail and noise; off: the model alone (smoother, may miss detail)
    merge_neighbours: Literal["auto", "on", "off"] = AUTO  # faithful: each frame's measurement merged with its neighbours'
                                            # where they agree with it: less noise and flicker, but a static scene's pixels
                                            # only; auto: on for a video from a static camera
    clipped_everywhere: Literal["model", "clip"] = "model"  # faithful, where every frame clipped: the model's level (smoothed;
                                            # right for a soft filmic shoulder) | at most the shortest exposure's clipping point
                                            # (the least the data says; right for a hard-clipping camera)
    denoise: Literal["auto", "on", "off"] = AUTO  # faithful: an adaptive Wiener filter against the frame's own noise read
                                            # through the camera: less noise, softer fine texture; auto: on for a stack's fused view
    hdr_format: Literal["pq", "hlg", "none"] = "pq"  # hdr.mp4 (hdr-video): HDR10 (SMPTE ST 2084: HDR TVs, phones, YouTube),
                                            # HLG (ARIB STD-B67: also right on SDR screens) or none (no file, no encode time)
    nits_white: float = setting(203.0, above=0.0, hi=1000.0)  # hdr.mp4: cd/m2 of diffuse white (BT.2408's reference white):
                                            # brighter pictures vs less room above white before the roll-off


@dataclass
class Config(Section):
    preset: str = "balanced"
    model: ModelConfig = field(default_factory=ModelConfig)
    scene: SceneConfig = field(default_factory=SceneConfig)
    tone: ToneConfig = field(default_factory=ToneConfig)
    blur: BlurConfig = field(default_factory=BlurConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    flow: FlowConfig = field(default_factory=FlowConfig)
    segment: SegmentConfig = field(default_factory=SegmentConfig)
    export: ExportConfig = field(default_factory=ExportConfig)

    def section_dict(self, *names: str) -> dict:
        return {n: dataclasses.asdict(getattr(self, n)) for n in names}

    def key_dict(self, *names: str) -> dict:
        """:meth:`section_dict` without the settings that cannot change a result (``keyed=False``)."""
        return {n: {f.name: getattr(getattr(self, n), f.name) for f in dataclasses.fields(getattr(self, n)) if f.metadata.get("keyed", True)} for n in names}

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def set(self, key: str, value: Any) -> None:
        """Set ``section.field`` from a string or a value, converted to the field's type and checked."""
        parts = key.split(".")
        if len(parts) != 2:
            raise LayercamError(f"--set expects section.field=value, got {key!r}")
        sec, name = parts
        if sec not in SECTIONS:
            raise LayercamError(f"unknown config section {sec!r} (one of {', '.join(SECTIONS)})")
        obj = getattr(self, sec)
        hints = _hints(type(obj))
        if name not in hints:
            raise LayercamError(f"unknown setting {key!r} (known: {', '.join(sorted(hints))})")
        setattr(obj, name, check_value(key, value, hints[name], _meta(type(obj), name)))

    def copy(self) -> "Config":
        """A settable copy (also of a frozen config)."""
        c = copy.deepcopy(self)
        for obj in [c] + [getattr(c, sec) for sec in SECTIONS]:
            obj.__dict__.pop("_frozen", None)
            obj.__dict__.pop("_name", None)
        return c


SECTIONS = tuple(f.name for f in dataclasses.fields(Config) if f.name != "preset")


# -- conversion and checks -----------------------------------------------------------------------
def _hints(cls) -> dict:
    return typing.get_type_hints(cls)


def _meta(cls, name: str) -> dict:
    return next(f.metadata for f in dataclasses.fields(cls) if f.name == name)


def _alternatives(hint) -> list:
    """``int | Literal["auto"]`` -> ``[int, Literal["auto"]]``; a plain type -> ``[type]``."""
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return list(typing.get_args(hint))
    return [hint]


def _describe(hint) -> str:
    """``Literal["a", "b"]`` -> "one of a, b"; ``int | Literal["auto"]`` -> "an integer or auto"."""
    kinds, choices = [], []
    for alt in _alternatives(hint):
        if typing.get_origin(alt) is Literal:
            choices += [str(c) for c in typing.get_args(alt)]
        else:
            kinds.append({bool: "true/false (on/off)", int: "an integer", float: "a number", str: "text"}.get(alt, str(alt)))
    if not kinds:
        return "one of " + ", ".join(choices)
    return " or ".join(kinds + choices)


def _as(value: Any, typ) -> Any:
    """``value`` (a string from ``--set`` or a TOML/JSON value) as ``typ``; ValueError when it is not."""
    if typing.get_origin(typ) is Literal:
        for c in typing.get_args(typ):
            if value == c and type(value) is type(c):
                return c
            if isinstance(value, str) and str(c) == value.strip():
                return c
        raise ValueError
    if typ is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str):
            v = value.strip().lower()
            if v in ("1", "true", "yes", "on"):
                return True
            if v in ("0", "false", "no", "off"):
                return False
        raise ValueError
    if isinstance(value, bool):  # bool is an int to Python, never to a setting
        raise ValueError
    if typ is int:
        if isinstance(value, int):
            return value
        if isinstance(value, float) and value.is_integer():
            return int(value)
        if isinstance(value, str):
            f = float(value)
            if f.is_integer():
                return int(f)
        raise ValueError
    if typ is float:
        if isinstance(value, (int, float)):
            return float(value)
        if isinstance(value, str):
            return float(value)
        raise ValueError
    if typ is str:
        if isinstance(value, str):
            return value
        raise ValueError
    raise ValueError


def check_value(key: str, value: Any, hint, meta: dict | None = None) -> Any:
    """``value`` converted to ``hint`` and checked against the field's range: one line on failure."""
    meta = meta or {}
    alts = sorted(_alternatives(hint), key=lambda a: typing.get_origin(a) is not Literal)  # choices first
    for alt in alts:
        try:
            v = _as(value, alt)
            break
        except (ValueError, TypeError, OverflowError):
            continue
    else:
        raise LayercamError(f"{key}: expected {_describe(hint)}, got {value!r}")
    if isinstance(v, float) and not math.isfinite(v):
        raise LayercamError(f"{key}: must be a finite number, got {value!r}")
    if isinstance(v, int) and not isinstance(v, bool) and abs(v) > INT_MAX:
        raise LayercamError(f"{key}: must be an integer of at most {INT_MAX}, got {value!r}")
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        lo, hi, above, below = meta.get("lo"), meta.get("hi"), meta.get("above"), meta.get("below")
        if lo is not None and v < lo:
            raise LayercamError(f"{key}: must be >= {lo:g}, got {v:g}")
        if hi is not None and v > hi:
            raise LayercamError(f"{key}: must be <= {hi:g}, got {v:g}")
        if above is not None and not v > above:
            raise LayercamError(f"{key}: must be > {above:g}, got {v:g}")
        if below is not None and not v < below:
            raise LayercamError(f"{key}: must be < {below:g}, got {v:g}")
    if meta.get("check") is not None:
        msg = meta["check"](v)
        if msg:
            raise LayercamError(f"{key}: {msg}, got {value!r}")
    return v


def validate(cfg: Config) -> Config:
    """Check every value of ``cfg`` (also those set in code) and the rules between them; returns it."""
    for sec in SECTIONS:
        obj = getattr(cfg, sec)
        for name, hint in _hints(type(obj)).items():
            check_value(f"{sec}.{name}", getattr(obj, name), hint, _meta(type(obj), name))
    if cfg.flow.method.startswith("raft") and not cfg.flow.raft_weights:
        raise LayercamError(f"flow.method={cfg.flow.method} needs a weights file: --set flow.raft_weights=PATH")
    if cfg.segment.detector and not os.path.isfile(cfg.segment.detector):
        raise LayercamError(f"segment.detector: no such file: {cfg.segment.detector!r}")
    return cfg


def model_overrides(layers=None, tone_mapper=None, blur=None, max_offset=None, flow_loss=None) -> list[str]:
    """The model choices of the command-line flags (``--layers 2 --blur 3x3 --max-offset 2
    --flow-loss off``; ``None``: left to the analysis) as ``--set`` items."""
    out = []
    if layers is not None:
        out.append(f"model.layers={layers}")
    if tone_mapper is not None:
        out.append(f"model.tone_mapper={tone_mapper}")
    if blur is not None:
        if blur == "off":
            out.append("model.blur=off")
        else:
            m = re.fullmatch(r"(\d+)x\1", str(blur))
            if not m:
                raise LayercamError(f"blur must be off or NxN (3x3, 5x5), got {blur!r}")
            out += ["model.blur=on", f"blur.n={m.group(1)}"]
    if max_offset is not None:
        out.append(f"blur.max_offset={max_offset}")
    if flow_loss is not None:
        out.append(f"model.flow_loss={'on' if flow_loss in (True, 'on') else 'off'}")
    return out


# -- presets -------------------------------------------------------------------------------------
def preset_names() -> list[str]:
    return sorted(p.name[:-5] for p in resources.files("layercam.configs").iterdir() if p.name.endswith(".toml"))


def _read_preset(name: str) -> dict:
    path = Path(name)
    if path.suffix == ".toml" and path.exists():
        if not path.is_file():
            raise LayercamError(f"preset {name}: not a file (a preset is a name or a .toml file)")
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            raise LayercamError(f"preset {name}: not a text file (a preset is TOML)") from None
        except OSError as e:
            raise LayercamError(f"preset {name}: cannot read it ({e.strerror or e})") from None
    else:
        res = resources.files("layercam.configs").joinpath(f"{name}.toml")
        if not res.is_file():
            raise LayercamError(f"unknown preset {name!r} (built in: {', '.join(preset_names())}; or a .toml path)")
        text = res.read_text()
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise LayercamError(f"preset {name}: {e}") from None


def preset_tag(preset: str) -> str:
    """A preset's name for folders and tables: the file's stem for a ``.toml`` preset file."""
    return Path(preset).stem if preset.endswith(".toml") else preset


def load_config(preset: str = "balanced", overrides: list[str] | None = None) -> Config:
    """Defaults, then the preset file's values, then each ``section.field=value`` override; checked."""
    cfg = Config(preset=preset_tag(preset))
    data = _read_preset(preset)
    for sec, values in data.items():
        if not isinstance(values, dict):
            raise LayercamError(f"preset {preset}: top-level key {sec!r} must be a [section]")
        for k, v in values.items():
            try:
                cfg.set(f"{sec}.{k}", v)
            except LayercamError as e:
                raise LayercamError(f"preset {preset}: {e}") from None
    for item in overrides or []:
        if "=" not in item:
            raise LayercamError(f"--set expects key=value, got {item!r}")
        k, v = item.split("=", 1)
        cfg.set(k.strip(), v.strip())
    return validate(cfg)


def config_hash(obj: Any) -> str:
    import hashlib

    return hashlib.sha1(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()


def config_from_dict(d: dict) -> Config:
    """Inverse of :meth:`Config.to_dict`, checked; unknown keys are ignored (older runs)."""
    cfg = Config(preset=d.get("preset", "custom"))
    for sec in SECTIONS:
        known = _hints(type(getattr(cfg, sec)))
        for k, v in (d.get(sec) or {}).items():
            if k in known:
                cfg.set(f"{sec}.{k}", v)
    return cfg
