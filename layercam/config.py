"""Dataclass configs for every component and stage, presets as TOML files, ``--set key=value``.

A preset (``configs/<name>.toml``, shipped inside the package as ``layercam.configs``) holds only
the values that differ from the defaults below. ``load_config("fast", ["train.steps=500"])``
returns a :class:`Config`; ``Config.section_dict("train")`` is what a stage hashes for its cache key.
"""

from __future__ import annotations

import dataclasses
import json
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from layercam.errors import LayercamError


@dataclass
class SceneConfig:
    """Scene model: deformation, atlas and alpha fields of each layer."""

    encoding: str = "grid"          # atlas encoding: "grid" (dense multi-res 2D grids) | "pe" (paper)
    pe_freqs: int = 7               # positional-encoding frequencies (paper: 7)
    grid_levels: int = 6            # dense grid levels, resolutions geometric from min to max
    grid_min_res: int = 16
    grid_max_res: int = 0           # 0: derived from the atlas's extent in pixels (see model.resolve_sizes)
    grid_features: int = 4
    atlas_width: int = 64           # atlas MLP width / depth (paper: 512 x 4)
    atlas_depth: int = 2
    deformation: str = "homography"  # "homography" (per-frame homography + residual MLP) | "mlp" (paper)
    deform_width: int = 64          # residual (homography) or full (mlp) deformation MLP (paper: 256 x 4)
    deform_depth: int = 2
    deform_pe_freqs: int = 4
    residual_scale: float = 0.05    # bound of the residual deformation, atlas units
    residual: str = "auto"          # the residual warp: auto (off for a static one-layer scene) | on | off
    bootstrap: str = "flow"         # "flow" (chained homographies of the cached flow) | "identity" (paper)
    alpha_width: int = 64
    alpha_depth: int = 3
    alpha_pe_freqs: int = 6


@dataclass
class ToneConfig:
    """Tone mapper: three per-channel MLPs of log2 r' + log2 dt (paper: 2 layers of 128)."""

    width: int = 64
    depth: int = 2
    monotone: bool = False          # monotone by construction (cumulative positive increments)
    c0: float = 0.5                 # white-balance target T(0)
    init_slope: float = 0.6         # initial curve sigmoid(init_slope * ln2 * z)
    lut: int = 1024                 # evaluate the curves on this many knots and interpolate (0: per pixel, paper)


@dataclass
class BlurConfig:
    """Blur generator (paper Sec. 3.2): n x n patch, offsets bounded by max_offset pixels."""

    n: int = 3
    max_offset: float = 5.0
    width: int = 64
    depth: int = 4
    init_centre_weight: float = 0.2  # start blurry: a near-sharp start (0.9) lets the scene absorb the blur
    zero_mean_offsets: bool = True  # a patch's offsets shape it but cannot translate it (no warp)
    centre: str = "auto"            # PSFs centred on their pixel: auto (a static one-layer scene) | on | off
    warmup: float = 0.2             # fraction of training with the PSFs held at their start: the scene first
                                    # takes shape; blur nets trained from step 0 collapse every PSF to a delta within 25 steps


@dataclass
class LossConfig:
    color: float = 1.0              # lambda_c
    flow: float = 100.0             # lambda_f, decays linearly to 0 by flow_decay_end of training
    flow_decay_end: float = 0.5
    white_balance: float = 1.0      # lambda_w
    gradient: float = 100.0         # lambda_g
    clipped: str = "plain"          # "plain" MSE (paper) | "one_sided" at 0 / 1 pixels
    rigidity: float = 0.01
    sparsity: float = 0.001
    alpha_flow: float = 1.0


@dataclass
class TrainConfig:
    steps: int = 2000
    bootstrap_steps: int = 200      # deformation fit to its bootstrap mapping (paper: 10k)
    batch: int = 8192               # pixels per step (paper: 30,000)
    lr: float = 5e-3                # Adam learning rate of MLPs (paper: 1e-4)
    grid_lr: float = 2e-2           # learning rate of dense grid tables
    lr_decay: float = 0.1           # final lr factor (cosine)
    seed: int = 0
    autocast: str = "auto"          # "auto" (bf16 mixed precision on a GPU, fp32 on the CPU) | "none" | "bf16"
    compile: bool = False          # torch.compile the atlas fields (opt-in: 10-30 s to compile)
    checkpoint_every: int = 500
    device: str = "cpu"
    max_bad_steps: int = 20


@dataclass
class FlowConfig:
    method: str = "dis_medium"      # "dis_fast" | "dis_medium" | "raft" (needs --raft-weights)
    raft_weights: str = ""


@dataclass
class ExportConfig:
    half: bool = True               # EXR half floats
    preview_fps: float = 0.0        # 0: the input's frame rate
    chunk: int = 65536


@dataclass
class Config:
    preset: str = "balanced"
    scene: SceneConfig = field(default_factory=SceneConfig)
    tone: ToneConfig = field(default_factory=ToneConfig)
    blur: BlurConfig = field(default_factory=BlurConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    flow: FlowConfig = field(default_factory=FlowConfig)
    export: ExportConfig = field(default_factory=ExportConfig)

    def section_dict(self, *names: str) -> dict:
        return {n: dataclasses.asdict(getattr(self, n)) for n in names}

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def set(self, key: str, value: Any) -> None:
        """Set ``section.field`` from a string or a value, converting to the field's type."""
        parts = key.split(".")
        if len(parts) != 2:
            raise LayercamError(f"--set expects section.field=value, got {key!r}")
        sec, name = parts
        if sec == "preset" or not hasattr(self, sec) or not dataclasses.is_dataclass(getattr(self, sec)):
            raise LayercamError(f"unknown config section {sec!r} (one of {', '.join(SECTIONS)})")
        obj = getattr(self, sec)
        fields = {f.name: f for f in dataclasses.fields(obj)}
        if name not in fields:
            raise LayercamError(f"unknown setting {key!r} (known: {', '.join(sorted(fields))})")
        current = getattr(obj, name)
        setattr(obj, name, _convert(value, type(current), key))


SECTIONS = ("scene", "tone", "blur", "loss", "train", "flow", "export")


def _convert(value: Any, typ: type, key: str) -> Any:
    if not isinstance(value, str):
        if typ is float and isinstance(value, int):
            return float(value)
        if isinstance(value, typ):
            return value
        raise LayercamError(f"{key}: expected {typ.__name__}, got {value!r}")
    try:
        if typ is bool:
            v = value.strip().lower()
            if v in ("1", "true", "yes", "on"):
                return True
            if v in ("0", "false", "no", "off"):
                return False
            raise ValueError(value)
        if typ is int:
            return int(float(value)) if float(value).is_integer() else int(value)
        if typ is float:
            return float(value)
        return value
    except ValueError:
        raise LayercamError(f"{key}: cannot read {value!r} as {typ.__name__}") from None


def preset_names() -> list[str]:
    return sorted(p.name[:-5] for p in resources.files("layercam.configs").iterdir() if p.name.endswith(".toml"))


def _read_preset(name: str) -> dict:
    path = Path(name)
    if path.suffix == ".toml" and path.exists():
        text = path.read_text()
    else:
        res = resources.files("layercam.configs").joinpath(f"{name}.toml")
        if not res.is_file():
            raise LayercamError(f"unknown preset {name!r} (built in: {', '.join(preset_names())}; or a .toml path)")
        text = res.read_text()
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise LayercamError(f"preset {name}: {e}") from None


def load_config(preset: str = "balanced", overrides: list[str] | None = None) -> Config:
    """Defaults, then the preset file's values, then each ``section.field=value`` override."""
    cfg = Config(preset=Path(preset).stem if preset.endswith(".toml") else preset)
    data = _read_preset(preset)
    for sec, values in data.items():
        if not isinstance(values, dict):
            raise LayercamError(f"preset {preset}: top-level key {sec!r} must be a [section]")
        for k, v in values.items():
            cfg.set(f"{sec}.{k}", v)
    for item in overrides or []:
        if "=" not in item:
            raise LayercamError(f"--set expects key=value, got {item!r}")
        k, v = item.split("=", 1)
        cfg.set(k.strip(), v.strip())
    if cfg.scene.residual not in ("auto", "on", "off"):
        raise LayercamError(f"scene.residual must be auto, on or off, got {cfg.scene.residual!r}")
    if cfg.blur.centre not in ("auto", "on", "off"):
        raise LayercamError(f"blur.centre must be auto, on or off, got {cfg.blur.centre!r}")
    if not 0.0 <= cfg.blur.warmup < 1.0:
        raise LayercamError(f"blur.warmup is a fraction of training in [0, 1), got {cfg.blur.warmup}")
    return cfg


def config_hash(obj: Any) -> str:
    import hashlib

    return hashlib.sha1(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()


def config_from_dict(d: dict) -> Config:
    """Inverse of :meth:`Config.to_dict` (unknown keys are ignored, for older runs)."""
    cfg = Config(preset=d.get("preset", "custom"))
    for sec in SECTIONS:
        obj = getattr(cfg, sec)
        names = {f.name for f in dataclasses.fields(obj)}
        for k, v in (d.get(sec) or {}).items():
            if k in names:
                setattr(obj, k, v)
    return cfg
