"""Typed settings: one dataclass per section, presets as TOML files, ``--set section.key=value``.

Every field is typed (``int``, ``float``, ``bool``, ``str``, a ``Literal`` of choices, or a number
or ``"auto"``) and carries its range in :func:`setting`; a value is converted and checked when it is
set, and the whole config once more when it is loaded (:func:`load_config`) or a run starts, so a
bad preset value or ``--set`` fails with one line before any work. NaN and infinities are refused
everywhere.

Presets and ``--set`` items are read by :mod:`layercam.core.presets` (``load_config``); a value is
converted and checked by :func:`layercam.core.values.check_value`. ``Config.key_dict("train")`` is
what a stage hashes for its cache key.

``"auto"`` values are decided per clip, once, by :func:`layercam.engine.resolve.resolve` (from what the
analysis measures), which returns the run's frozen settings; sizes that follow from the clip (the atlas
grid's finest level, the alpha grid) are derived in code, and fixed sizes and weights are named
constants in the modules that use them. Each setting's comment says what it trades.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import os
import re
import typing
from dataclasses import dataclass, field
from typing import Any, Literal

from layercam.core.errors import LayercamError
from layercam.core.values import check_value

AUTO = "auto"
DEFAULT_PRESET = "balanced"  # the preset a command and a Config start from when none is named


class Section:
    """Base of the settings' dataclasses: settable while a :class:`Config` is built (defaults,
    preset, ``--set``), frozen once resolved (:func:`freeze`; :mod:`layercam.engine.resolve`)."""

    def __setattr__(self, name, value):
        if getattr(self, "_frozen", False):
            raise dataclasses.FrozenInstanceError("settings are resolved once "
                                                  "(layercam.engine.resolve): cannot set "
                                                  f"{getattr(self, '_name', '')}{name}")
        object.__setattr__(self, name, value)


def freeze(cfg: "Config") -> "Config":
    """``cfg`` made read-only, in place (each section and the config); returns it."""
    for sec in SECTIONS:
        obj = getattr(cfg, sec)
        object.__setattr__(obj, "_name", f"{sec}.")
        object.__setattr__(obj, "_frozen", True)
    object.__setattr__(cfg, "_frozen", True)
    return cfg


def setting(default: Any, lo: float | None = None, hi: float | None = None, *,
            above: float | None = None, below: float | None = None, check=None,
            keyed: bool = True) -> Any:
    """A dataclass field with a range: ``lo <= v <= hi``, ``v > above``, ``v < below`` (numbers;
    ``"auto"`` is not range-checked) and ``check(v) -> str | None`` (a message when wrong).
    ``keyed=False``: the setting cannot change a stage's result (how often to save), so it is left
    out of the cache keys (:meth:`Config.key_dict`)."""
    return field(default=default,
                 metadata={"lo": lo, "hi": hi, "above": above, "below": below, "check": check,
                           "keyed": keyed})


def _odd(v) -> str | None:
    return None if v == AUTO or v % 2 == 1 else "must be odd"


def _device(v: str) -> str | None:
    return None if re.fullmatch(r"auto|cpu|mps|cuda(:\d+)?", v) else "expected auto, cpu, cuda, cuda:N or mps"


def _lut(v: int) -> str | None:
    return None if v == 0 or v >= 2 else "must be 0 (off) or at least 2 knots"


@dataclass
class ModelConfig(Section):
    """What the model contains. ``auto``: decided for the clip by :func:`layercam.engine.resolve.resolve`
    from what the analysis measured; anything else forces the choice (``--layers``, ``--blur``, ...)."""

    layers: Literal["auto", 1, 2] = AUTO              # 1: one atlas (static or rigid scene); 2: a
                                                      # foreground layer for an
                                                      # object moving on its own (an alpha field, twice the atlases)
    tone_mapper: Literal["auto", "learned", "fixed"] = AUTO  # learned CRF (needs exposures that
                                                             # differ) | the fixed sRGB curve
    exposures: Literal["auto", "given", "learned"] = AUTO  # learned where the exposure spec leaves them unknown
    blur: Literal["auto", "on", "off"] = AUTO           # the blur generator: sharp output from
                                                        # blurry frames, at 2-3 x the time
    flow_loss: bool | Literal["auto"] = AUTO            # flow consistency: keeps moving content
                                                        # registered; nothing to do on a static
                                                        # scene


@dataclass
class SceneConfig(Section):
    """Scene model: deformation, atlas and alpha fields of each layer (fixed sizes and constants:
    :mod:`layercam.scene.fields`)."""

    encoding: Literal["grid", "pe"] = "grid"  # atlas encoding: dense multi-resolution 2D grids
                                              # (fast) | positional encoding
                                              # (the paper's PE(7) -> MLP: 1-2 orders of magnitude slower on a CPU)
    grid_levels: int = setting(6, 1, 16)     # grid levels between 16 cells and the atlas's extent:
                                             # finer detail vs fitting
                                             # the frames' noise (quality: 8)
    atlas_width: int = setting(64, 1)        # atlas MLP width and depth: capacity vs time per step (paper: 512 x 4)
    atlas_depth: int = setting(2, 0)         # ... its hidden layers
    deformation: Literal["homography", "mlp"] = "homography"  # per-frame homography + bounded
                                                              # residual MLP (starts exact
                                             # from the flow) | one MLP of (x, y, t) (paper: fitted to its start first)
    deform_width: int = setting(64, 1)       # the deformation MLP's width and depth: non-rigid
                                             # detail vs time (paper: 256 x 4)
    deform_depth: int = setting(2, 0)        # ... its hidden layers
    bootstrap: Literal["flow", "identity"] = "flow"  # the mappings' start: chained flow homographies | identity (paper)
    alpha_encoding: Literal["pe", "grid"] = "grid"  # alpha from a positional encoding alone (smooth
                                                    # outlines, the paper's)
                                             # | also dense (x, y, t) grids (thin parts; memory grows with the frames)


@dataclass
class ToneConfig(Section):
    """Tone mapper: three per-channel MLPs of log2 r' + log2 dt (paper: 2 layers of 128)."""

    width: int = setting(64, 1)      # each channel's MLP: width and depth (paper: 128 x 2); a wider
                                     # curve fits more bends
    depth: int = setting(2, 0)       # ... its hidden layers
    lut: int = setting(1024, 0, check=_lut)  # the curves evaluated on this many knots and interpolated (error < 1e-4):
                                     # a step's tone mapping costs the knots, not the batch; 0: per pixel (paper)


@dataclass
class BlurConfig(Section):
    """Blur generator (paper Sec. 3.2): an n x n patch per pixel, offsets bounded by max_offset pixels
    (its nets' sizes and schedule: :mod:`layercam.camera.blur`)."""

    n: int = setting(3, 1, 15, check=_odd)  # patch side, n^2 scene look-ups per pixel: 3 as the
                                            # paper, whose learned offsets
                                            # reach wide blur (5 fitted no better where the blur is
                                            # wide, at 2.8x the cost)
    max_offset: float | Literal["auto"] = setting(AUTO, 0.0, 64.0)  # s, px: how far the patch may
                                                                    # spread; too little cannot
                                                                    # model the blur, too much lets
                                                                    # it fit noise; auto: measured


@dataclass
class LossConfig(Section):
    """Loss terms whose weight a preset or a clip changes (the paper's fixed weights: :mod:`layercam.engine.model`)."""

    robust: float | Literal["auto"] = setting(AUTO, 0.0, 1.0)  # colour error: 0 MSE (paper); c > 0 Cauchy
                                                 # c^2 ln(1 + (e / c)^2), errors past c (pixel
                                                 # value) count less: a bracket's
                                                 # shots that disagree bend the curve less, but
                                                 # edges fit less; auto: 0.05
                                                 # for fuse-stack without a blur generator, MSE elsewhere
    alpha_flow_keep: float = setting(0.25, 0.0, 1.0)  # two layers: share of the alpha flow weight
                                                      # kept once the flow has
                                                 # decayed (1: all through, as Kasten et al.): holds
                                                 # alpha on its object in a
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
                                            # fields; on a CPU that computes bf16 natively (AVX512-BF16,
                                            # AMX) faster with a blur generator (its patches' large
                                            # products), slower on one that emulates it;
                                            # auto: bf16 on a GPU that has it, fp32 elsewhere
    checkpoint_every: int = setting(500, 0, keyed=False)  # steps between checkpoints: work lost to
                                                          # a crash vs time spent saving
                                            # (0: only at the end and on Ctrl-C)
    device: str = setting("auto", check=_device)  # auto: CUDA when torch sees a GPU, else the CPU
    passes_per_frame: float = setting(2.0, 0.0)  # at most this many passes over the clip's pixels
                                                 # per frame of the clip:
                                            # more fit a short stack's noise and take time (0: no
                                            # cap, the preset's steps;
                                            # paper: 0)


@dataclass
class FlowConfig(Section):
    method: Literal["dis_ultrafast", "dis_fast", "dis_medium", "raft", "raft_small",
                    "raft_large"] = "dis_medium"  # OpenCV
                                            # DIS (no weights; faster is coarser) | torchvision RAFT
                                            # from raft_weights ("raft":
                                            # the variant the file holds): finer on large motion,
                                            # ~0.5-1.5 s a pair on a CPU
    raft_weights: str = ""                  # a local torchvision RAFT state dict for the raft
                                            # methods (never downloaded)


@dataclass
class SegmentConfig(Section):
    """The foreground finder of a two-layer clip (:mod:`layercam.vision.segment`: the camera's motion read
    from the frame's border, what moves against it followed over frames, grown to the object) and
    the foreground layer's bootstrap. Every other number of the finder is derived from the clip (its
    size, its flow's measured noise) or named once in its module.
    """

    reach: int = setting(8, 1, 64)          # frames each pixel is followed to (1, 2, 4, .. reach): more finds slower
                                            # objects (grazing cows move 0.1-0.5 px a frame) and costs a pair each
    k_sigma: float = setting(4.0, 0.0)      # noise levels (the pair's robust spread, the flow's measured noise) a
                                            # residual must exceed to be motion: lower finds fainter motion and more
                                            # of the background's own (water, foliage)
    foreground: Literal["object", "identity"] = "object"  # the foreground layer's starting mapping: the object's own
                                            # motion (its atlas holds it still) | the identity (the paper's start)
    margin: float = setting(0.6, above=0.0, hi=1.0)  # the share of the foreground atlas the masked object fills at the
                                            # start: more texels for it, less slack for what the masks missed
    detector: str = ""                      # a torchvision Mask R-CNN weights file
                                            # (layercam.vision.segment.detect); "": the motion masks
                                            # alone
    detector_score: float = setting(0.5, 0.0, 1.0)   # the detector's instances scoring at least
                                                     # this: lower finds more, and more wrongly
    detector_overlap: float = setting(0.3, above=0.0, hi=1.0)  # an instance replaces a frame's mask
                                                               # where this share of it lies
                                            # in the mask: lower trusts the detector over the motion
    detector_size: int = setting(800, 64, 4096)  # the short side (px) the detector sees: more finds
                                                 # smaller objects, slower


@dataclass
class ExportConfig(Section):
    half: bool = True                       # EXR half floats: half the disk, 3e-4 relative error
    reference: int | Literal["middle", "first", "last"] = "middle"  # fuse-stack: the view fused
                                                                    # into (an index may be
                                                                    # negative)
    faithful: bool = True                   # each frame's HDR agrees with the frame where it saw
                                            # well (layercam/camera/faithful.py):
                                            # the frame's own detail and noise; off: the model alone
                                            # (smoother, may miss detail)
    merge_neighbours: Literal["auto", "on", "off"] = AUTO  # faithful: each frame's measurement
                                                           # merged with its neighbours'
                                            # where they agree with it: less noise and flicker, but
                                            # a static scene's pixels
                                            # only; auto: on for a video from a static camera
    clipped_everywhere: Literal["model", "clip"] = "model"  # faithful, where every frame clipped:
                                                            # the model's level (smoothed;
                                            # right for a soft filmic shoulder) | at most the
                                            # shortest exposure's clipping point
                                            # (the least the data says; right for a hard-clipping camera)
    denoise: Literal["auto", "on", "off"] = AUTO  # faithful: an adaptive Wiener filter against the
                                                  # frame's own noise read
                                            # through the camera: less noise, softer fine texture;
                                            # auto: on for a stack's fused view
    hdr_format: Literal["pq", "hlg", "none"] = "pq"  # hdr.mp4 (hdr-video): HDR10 (SMPTE ST 2084:
                                                     # HDR TVs, phones, YouTube),
                                            # HLG (ARIB STD-B67: also right on SDR screens) or none
                                            # (no file, no encode time)
    nits_white: float = setting(203.0, above=0.0, hi=1000.0)  # hdr.mp4: cd/m2 of diffuse white
                                                              # (BT.2408's reference white):
                                            # brighter pictures vs less room above white before the roll-off


@dataclass
class Config(Section):
    preset: str = DEFAULT_PRESET
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
        return {n: {f.name: getattr(getattr(self, n), f.name)
                    for f in dataclasses.fields(getattr(self, n)) if f.metadata.get("keyed", True)}
                for n in names}

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

