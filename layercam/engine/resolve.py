"""Resolve once: every ``auto`` setting and every cap of one run, decided with its reason.

:func:`resolve` takes the settings as the user gave them (a preset and ``--set``; :class:`Config`)
and what the analysis measured of the clip (:func:`layercam.vision.analyse.measure`) and returns a
:class:`Resolved`: the only settings object the stages after the flow, the model and the trainer
read. ``report.json`` stores it (``"settings"``), the analysis table prints from it, and each
stage's cache key hashes the part of it that the stage reads.

What it decides, each with a reason in ``Resolved.reasons`` (keyed ``section.field``):

* the model's components (``model.*``) and the blur generator's reach (``blur.max_offset``),
  the colour loss (``loss.robust``): :func:`layercam.engine.decide.decide`, from what
  :func:`layercam.vision.analyse.measure` measured;
* ``static``: the camera did not move (the flow's chained homographies move no frame corner by
  :data:`layercam.core.geometry.STATIC_CORNER_PX`; with ``scene.bootstrap=flow``). A static one-layer
  scene then has no residual warp and blur PSFs centred on their pixel, a static two-layer scene
  a background held still (:attr:`Resolved.residual`, :attr:`still_background`, :attr:`blur_centre`);
* the step cap (``train.steps``, and where it shortens training ``scene.grid_levels``, and at its
  floor the floor's model, :data:`FLOOR`): only where the preset allows a cap
  (``train.passes_per_frame`` > 0; `paper` trains the paper's steps);
* the export's ``merge_neighbours`` and ``denoise`` from the task and ``static``;
* ``train.device`` and ``train.autocast`` from what torch sees (:func:`device_of`: the one place
  ``auto`` becomes a device).

:func:`resolve` runs once per run, after the analysis (and once more only when the bootstrap's
foreground finder overturns a two-layer choice); the estimates before it bound the cost with the
same step cap (:func:`cap`, :func:`layercam.engine.estimate.bound`).

>>> from layercam.core.presets import load_config
>>> r = resolve(load_config("fast", ["model.layers=1", "model.blur=off"]), frames=3, hw=(256, 256), task="fuse-stack")
>>> r.settings.train.steps, r.reasons["train.steps"].split(":")[0]
(300, '300 steps of 4096 pixels instead of 600')
>>> r.settings.train.steps = 5
Traceback (most recent call last):
...
dataclasses.FrozenInstanceError: settings are resolved once (layercam.engine.resolve): cannot set train.steps
"""

from __future__ import annotations

from dataclasses import dataclass, field

import functools
import math

from layercam.core.config import AUTO, Config, config_from_dict, freeze

STATIC_KEY = "static"

FLOOR_GRID_LEVELS = 6        # a clip whose training the step cap shortens (a short stack: few looks at each
                             # scene point) gets at most this many atlas grid levels (`quality` has 8):
                             # more scales between the same coarsest and finest fitted its few shots'
                             # disagreements. docs/measurements.md
MIN_STEPS = 300              # the step cap's floor: a clip the cap gives fewer steps trains this many (and FLOOR)
MIN_SAMPLES_PRESET = "fast"  # ... with a blur generator, the floor in pixels sampled: this preset's steps x batch
                             # (min_samples), in the preset's model and batch: its PSFs learn after a warm-up
FLOOR = {"scene.grid_levels": FLOOR_GRID_LEVELS, "scene.atlas_width": 64, "train.batch": 4096}
                             # ... and one the cap puts at its floor (MIN_STEPS; a 3-shot stack of
                             # up to ~300x300 px) trains this model whatever the preset (the batch at most
                             # this): on the NTIRE crops and twelve taipei crops no preset's difference
                             # there was larger than the spread of three seeds, larger batches learned a
                             # softer tone shoulder and more steps fitted the shots' noise. Not with a
                             # blur generator (min_samples). docs/measurements.md


@dataclass(frozen=True)
class Resolved:
    """The run's settings, every ``auto`` decided and every cap applied (frozen), what was
    measured to decide whether the camera is static, and why each setting has its value."""

    settings: Config
    static: bool = False
    reasons: dict = field(default_factory=dict)

    @property
    def residual(self) -> bool:
        """The homography deformation's residual warp: off for a static one-layer scene (nothing
        for a free per-pixel warp to follow; it bent the frames to fit their blur instead)."""
        return not (self.static and self.settings.model.layers == 1)

    @property
    def still_background(self) -> bool:
        """Two layers from a static camera: the background maps every frame through its bootstrap
        homography alone (a per-frame correction let it wander a pixel and flicker)."""
        return self.static and self.settings.model.layers > 1

    @property
    def blur_centre(self) -> bool:
        """The blur PSFs' weighted centre held on its pixel: a static one-layer scene (a shift has
        nothing to follow there); free on moving footage."""
        return self.static and self.settings.model.layers == 1

    def section(self, *names: str) -> dict:
        """``{name: {field: value}}`` of the settings' sections ``names`` (a stage's cache key)."""
        return self.settings.section_dict(*names)

    def to_dict(self) -> dict:
        return {**self.settings.to_dict(), STATIC_KEY: self.static, "reasons": dict(self.reasons)}

    @classmethod
    def from_dict(cls, d: dict) -> "Resolved":
        """Inverse of :meth:`to_dict` (a checkpoint's or a report's ``"settings"``)."""
        return cls(freeze(config_from_dict(d)), bool(d.get(STATIC_KEY, False)), dict(d.get("reasons", {})))


def resolve(cfg: Config, clip=None, exposures=None, task: str = "hdr-video",
            measures: dict | None = None, *, frames: int | None = None,
            hw: tuple[int, int] | None = None) -> Resolved:
    """``cfg`` with every ``auto`` decided and every cap applied, for ``clip`` (or a clip of
    ``frames`` frames of size ``hw``) with ``exposures`` and the analysis's ``measures``."""
    from layercam.core.geometry import STATIC_CORNER_PX
    from layercam.engine.decide import decide

    if clip is None:
        clip = ClipShape(frames or 1, *(hw or (1, 1)))
    if exposures is None:
        from layercam.io import Exposures

        import numpy as np

        exposures = Exposures(np.zeros(clip.T), "none", None, "none", "single")
    cfg, why = decide(cfg, clip, exposures, task, measures)
    reasons = {(k if "." in k else (f"blur.{k}" if k == "max_offset" else f"model.{k}")): v for k, v in why.items()}
    mm = measures or {}

    shift = mm.get("corner_shift_px")
    static = cfg.scene.bootstrap == "flow" and shift is not None and clip.T > 1 and shift < STATIC_CORNER_PX
    if cfg.scene.bootstrap != "flow":
        reasons[STATIC_KEY] = "no: the mappings start from the identity (scene.bootstrap=identity)"
    elif shift is None or clip.T < 2:
        reasons[STATIC_KEY] = "no: no flow measured"
    else:
        reasons[STATIC_KEY] = (f"{'yes' if static else 'no'}: the flow's chained homographies move "
                               f"a frame corner {shift:.2f} px ({'<' if static else '>='} "
                               f"{STATIC_CORNER_PX})")

    cap(cfg, clip, reasons)

    e = cfg.export
    if e.merge_neighbours == AUTO:
        e.merge_neighbours = "on" if static and task != "fuse-stack" else "off"
        reasons["export.merge_neighbours"] = ("a video from a static camera: each frame merged "
                                              "with its neighbours where they agree with it"
                                              if e.merge_neighbours == "on"
                                              else "a moving camera or a stack's fused view: each "
                                                   "frame its own")
    if e.denoise == AUTO:
        e.denoise = "on" if task == "fuse-stack" else "off"
        reasons["export.denoise"] = ("a stack's fused view: filtered against the reference shot's "
                                     "own noise" if e.denoise == "on"
                                     else "a video: each frame keeps its own noise (filtered by "
                                          "their different noise, short and long frames flickered)")
    t = cfg.train
    if t.device == AUTO:
        t.device = device_of(AUTO)
        reasons["train.device"] = ("torch sees a CUDA device" if t.device.startswith("cuda")
                                   else "torch sees no CUDA device")
    if t.autocast == AUTO:
        t.autocast = "bf16" if t.device.startswith("cuda") and _bf16() else "none"
        hint = ("; this CPU computes bf16 natively: train.autocast=bf16 trains a blur generator faster"
                if t.device == "cpu" and cfg.model.blur == "on" and cpu_bf16() else "")
        reasons["train.autocast"] = ("bf16 mixed precision on a GPU that has it" if t.autocast == "bf16"
                                     else f"fp32 (no GPU with bf16{hint})")
    return Resolved(freeze(cfg), bool(static), reasons)


def cap(cfg: Config, clip, reasons: dict) -> None:
    """The step cap (:func:`step_cap`) for ``clip`` (anything with ``T``, ``H``, ``W``), its grid
    levels and its floor's model, written into ``cfg`` with their reasons; nothing where the preset
    asks for no cap."""
    t, s = cfg.train, cfg.scene
    if t.passes_per_frame <= 0:
        reasons["train.steps"] = f"{t.steps}: the preset's steps (train.passes_per_frame=0: no cap)"
        return
    blur = cfg.model.blur == "on"
    cap = step_cap(t, clip.T, clip.H * clip.W, blur)
    if cap >= t.steps:
        reasons["train.steps"] = (f"{t.steps}: the preset's (under its cap of "
                                  f"{t.passes_per_frame:g} x {clip.T} passes over the clip's "
                                  "pixels)")
        return
    asked = t.steps
    t.steps = cap
    t.bootstrap_steps = min(t.bootstrap_steps, cap // 2)
    if s.grid_levels > FLOOR_GRID_LEVELS:
        s.grid_levels = FLOOR_GRID_LEVELS
        reasons["scene.grid_levels"] = (f"{FLOOR_GRID_LEVELS}: a capped training fits the few "
                                        "looks' disagreements with more")
    floor = cap == MIN_STEPS and has_floor_model(cfg)  # (a blur generator keeps its floor in pixels sampled)
    if floor:
        s.grid_levels, s.atlas_width = FLOOR["scene.grid_levels"], min(s.atlas_width, FLOOR["scene.atlas_width"])
        t.batch = min(t.batch, FLOOR["train.batch"])
        reasons["train.steps"] = (f"{t.steps} steps of {t.batch} pixels instead of {asked}: a clip "
                                  "this short trains at the step cap's floor, one model "
                                  f"whatever the preset ({s.grid_levels} grid levels, atlas width "
                                  f"{s.atlas_width}; more fit a short stack's noise; "
                                  "train.passes_per_frame=0: no cap)")
    else:
        reasons["train.steps"] = (f"{t.steps} instead of {asked}: at most {t.passes_per_frame:g} x "
                                  f"{clip.T} passes over the clip's "
                                  f"{clip.T * clip.H * clip.W:,} pixels (more fit a short stack's "
                                  "noise; train.passes_per_frame=0: no cap)")


def has_floor_model(cfg: Config) -> bool:
    """Whether a clip ``cfg`` trains at the step cap's floor gets :data:`FLOOR`'s model: grid
    atlases without a blur generator (the floor was measured there; a blur generator keeps
    :func:`min_samples`, and `paper`'s positional encoding its own width and batch)."""
    return cfg.model.blur != "on" and cfg.scene.encoding == "grid"


def step_cap(train, frames: int, pixels: int, blur: bool = False) -> int:
    """The most steps ``train`` (a :class:`layercam.core.config.TrainConfig`) may take on a clip of
    ``frames`` frames of ``pixels`` pixels each: ``passes_per_frame * frames`` passes over its
    ``frames * pixels`` pixels in batches of ``train.batch``, but never fewer than :data:`MIN_STEPS`
    (the floor, where :func:`resolve` also sets :data:`FLOOR`), or with a ``blur``
    generator never fewer pixels sampled than :func:`min_samples`; ``passes_per_frame = 0``:
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
    >>> step_cap(TrainConfig(steps=2000, batch=8192), 3, 256 * 256, blur=True)  # a focus stack: min_samples()
    300
    >>> step_cap(TrainConfig(steps=600, batch=4096), 4, 32 * 32, blur=True)
    600
    """
    if train.passes_per_frame <= 0:
        return int(train.steps)
    need = math.ceil(train.passes_per_frame * frames * frames * pixels / train.batch)
    floor = math.ceil(min_samples() / train.batch) if blur else MIN_STEPS
    return int(min(train.steps, max(need, floor, 1)))


@functools.cache
def min_samples() -> int:
    """The blur generator's floor in pixels sampled: ``MIN_SAMPLES_PRESET``'s steps x batch (its PSFs
    were measured to learn after that warm-up)."""
    from layercam.core.presets import load_config

    t = load_config(MIN_SAMPLES_PRESET).train
    return int(t.steps) * int(t.batch)


TABLE_KEYS = ("window", "static", "train.steps", "scene.grid_levels", "export.merge_neighbours",
              "export.denoise", "train.device", "train.autocast")


def format_table(r: Resolved, windows: int = 1) -> str:
    """The analysis table a run prints: the model's components, then every other resolved setting
    that has a reason, one line each: name, value, why (``window``: a long clip's ``windows``,
    ``layercam.pipelines.windows``)."""
    from layercam.engine.decide import MODEL_KEYS, model_summary

    summary = model_summary(r.settings)
    keys = {"max_offset": "blur.max_offset"}
    rows = [(k, str(summary[k]), r.reasons.get(keys.get(k, f"model.{k}"), "")) for k in MODEL_KEYS]
    for k in TABLE_KEYS:
        if k in r.reasons:
            value = r.static if k == STATIC_KEY else windows if k == "window" else getattr(
                getattr(r.settings, k.split(".")[0]), k.split(".")[1])
            reason = r.reasons[k].split(": ", 1)[1] if k == STATIC_KEY else r.reasons[k]
            rows.append((k, str(value), reason))
    w0 = max(len(a) for a, _, _ in rows)
    w1 = max(len(b) for _, b, _ in rows)
    return "\n".join(f"  {a:<{w0}}  {b:<{w1}}  {c}" for a, b, c in rows)


@dataclass
class ClipShape:
    """A clip's size where only its size is known (``T`` frames of ``H x W``)."""

    T: int
    H: int
    W: int


def device_of(name: str) -> str:
    """A ``train.device`` (or a command's ``--device``) as the device it names, checked against what
    torch sees: ``auto`` is CUDA when torch sees a GPU, else the CPU (the one place it is decided)."""
    import torch

    from layercam.core.errors import LayercamError

    if name == AUTO:
        return "cuda" if torch.cuda.is_available() else "cpu"
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise LayercamError(f"--device {name} asked for, but torch sees no CUDA device")
    return name


def _bf16() -> bool:
    import torch

    return bool(torch.cuda.is_available() and torch.cuda.is_bf16_supported())


def cpu_bf16() -> bool:
    """Whether this CPU computes bf16 matrix products natively (AVX512-BF16 or AMX); elsewhere
    oneDNN emulates them, slower than float32."""
    import torch

    return any(bool(getattr(torch.cpu, name, lambda: False)())
               for name in ("_is_avx512_bf16_supported", "_is_amx_tile_supported"))


def as_resolved(cfg, frames: int = 1, hw: tuple[int, int] = (1, 1)) -> Resolved:
    """``cfg`` as a :class:`Resolved`: itself, or a :class:`Config` resolved with nothing measured
    for a clip of ``frames`` frames of size ``hw`` (a model built in code: its forced settings kept,
    the rest decided as for a clip whose flow says nothing)."""
    if isinstance(cfg, Resolved):
        return cfg
    return resolve(cfg.copy(), frames=frames, hw=hw)


__all__ = ["Resolved", "resolve", "as_resolved", "cap", "device_of", "format_table", "step_cap"]
