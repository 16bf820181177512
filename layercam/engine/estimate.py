"""What a run will cost, known before the work: peak memory and disk from the clip's size, the
preset and the settings, and a one-line refusal of what cannot fit.

:func:`estimate` takes the clip's size (``layercam.io.probe_clip``: a video's header, the first
image) and a config; the model's ``auto`` choices not yet made by the analysis are taken at their
costliest plausible value (two layers for a clip of more than one frame, the blur generator for
deblur-video and fuse-stack, or the ``n`` given, and an atlas as wide as its grid holds: the camera's
motion is not known before the flow), so that what is said before the work is an upper bound of what
the analysis can choose; the run says it again once the analysis has chosen and the flow has measured
how far the camera moves (:func:`layercam.pipelines.tasks.run_task`). The model's parameters are counted
exactly (the model is built on PyTorch's meta device: no memory); what a training step keeps per sample is measured on a
small stand-in of the model (:func:`layercam.engine.model_cost.kept_for_backward`); the other working sets are per-pixel
costs measured on this project's runs (``docs/measurements.md``), scaled by what each
stage holds at once: a pair of frames (flow), at most ``analyse.MOTION_PAIRS`` pairs (analysis), a
window of at most ``segment.long.SEG_FRAMES`` frames at the finder's working size (two-layer
bootstrap), the model, its optimiser and
a batch (training), a frame and a render chunk (export). None of them grows with the clip's length
except the alpha grid's slices up to ``scene.fields.ALPHA_GRID_CELLS`` (and, before the analysis, the
widest atlas the frames could span, up to the grid's cap: :func:`widest_atlas`); the disk does.

:func:`check` refuses (``LayercamError``, one line) an estimate above the memory available
(``MemAvailable``) or the free disk of the run folder, naming the estimate, its largest part and
what to change.
"""

from __future__ import annotations

import math
import os
import shutil
from pathlib import Path

import numpy as np

from layercam.core.config import AUTO
from layercam.core.errors import LayercamError
from layercam.engine.model_cost import floats_per_sample, kept_for_backward, model_parts

# measured costs, see docs/measurements.md: this process after its imports, and per pixel / per sample
# of what each stage holds at once. Fitted to readings of /proc (kB / 1024: MiB, 2^20 B), so in MiB
# and scaled by MIB to bytes (the estimate is said in bytes: 1 GB = 1e9 B)
MIB = 2**20 / 1e6
BASE = 700e6 * MIB       # python, torch, OpenCV and layercam imported, a clip opened (VmRSS 680-700
                         # MiB on this machine)
FLOW_PER_PX = 180.0 * MIB      # per working-grid pixel of a pair: the two frames, flows, checks, DIS
ANALYSIS_PER_PX = 28.0 * MIB   # per working-grid pixel of each pair measured (flow in float32, residuals, chains)
SEG_PER_PX = 23.0 * MIB        # two layers, a clip segmented whole: per pixel of the flow's grid of each frame
SEG_WORK_PER_PX = 70.0 * MIB   # two layers, a clip segmented in windows: per pixel of the finder's
                               # working size of each window frame
BOOT_PER_PX = 24.0 * MIB       # one layer: per frame pixel (a frame and its temporaries)
EXPORT_PER_PX = 455.0 * MIB    # per frame pixel: the faithful export's arrays for a frame and its
                               # two neighbours and their
EXPORT_FIXED = 240e6 * MIB     # geometry kept for the atlases, and what it holds at any frame size
                               # (the writers, the atlases'
                               # images): fitted to fast's exports of 24 frames at
                               # 427x240..1920x1080 (within 0..14%) and Basler's
RENDER_SHARE = 0.25      # a render chunk's pixel holds this share of what a training sample keeps (no autograd: the
                         # networks' layers one at a time): fast 1600 B measured against 6144 kept,
                         # paper 9 kB against 38 kB
RENDER_CHUNK = 65536     # pixels rendered at once (layercam.scene.render: frames, atlases, the tone mapping of both)
PARAM_BYTES = 23.3 * MIB # per model parameter in training: value, Adam's two moments, a dense
                         # part's gradient (the sparse
                         # grid levels' are rows) and what the step's scratch adds: fitted to fast's
                         # training peaks on twelve
                         # clips, 64x64 to 1920x1080, 0.35-75 M parameters (within -12..+8%)
GRAD_FACTOR = 1.4        # a training step's peak over what autograd keeps for the backward pass (a layer's gradients
                         # at a time besides): paper, 2 layers, 64x64 frames: 1.39; fast 2.0 (there 67 MB in all)


def _fmt(b: float) -> str:
    for unit, scale in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if b >= scale or unit == "MB":
            return f"{b / scale:.3g} {unit}"
    return f"{b:.0f} B"


def costliest(cfg, task: str, frames: int, hw: tuple[int, int] = (2, 2)):
    """A copy of ``cfg`` with each model ``auto`` at its costliest plausible choice (see the module;
    two layers need frames of 2 pixels or more across: a 1x1 clip is one layer)."""
    c = cfg.copy()
    m, b = c.model, c.blur
    if m.layers == AUTO:
        m.layers = 2 if frames > 1 and max(hw) > 1 else 1
    if m.tone_mapper == AUTO:
        m.tone_mapper = "learned"
    if m.exposures == AUTO:
        m.exposures = "learned"
    if m.blur == AUTO:
        m.blur = "on" if task in ("deblur-video", "fuse-stack") else "off"
    if m.flow_loss == AUTO:
        m.flow_loss = frames > 1
    if b.max_offset == AUTO:
        b.max_offset = 5.0
    return c


def bound(cfg, task: str, frames: int, hw: tuple[int, int]):
    """``cfg`` as the settings the estimate costs: the run's resolution itself when given one (after
    the analysis: :class:`~layercam.engine.resolve.Resolved`), else (before it) the costliest model
    :func:`costliest` allows, under the step cap that :func:`layercam.engine.resolve.cap` puts on a
    clip of ``frames`` frames of ``hw`` (fewer grid levels, a smaller batch at its floor) and with
    nothing measured (the camera not static; the colour loss's scale as given, else MSE; the
    device and precision leave no trace in the cost). Nothing is resolved here: the run resolves
    once, after the analysis."""
    from layercam.core.config import freeze
    from layercam.engine.resolve import ClipShape, Resolved, cap

    if isinstance(cfg, Resolved):
        return cfg
    c = costliest(cfg, task, frames, hw)
    cap(c, ClipShape(frames, *hw), {})
    if c.loss.robust == AUTO:
        c.loss.robust = 0.0
    return Resolved(freeze(c))


def widest_atlas(frames: int, hw: tuple[int, int]) -> float:
    """The widest atlas (frame pixels across) a model of ``frames`` frames of ``hw`` can be sized
    for, whatever the camera's motion: the frames side by side, at most what the grid holds
    (``layercam.scene.layered.GRID_RES_RANGE``; a wider pan is cut into windows)."""
    from layercam.core.geometry import atlas_mappings, atlas_pixels
    from layercam.scene.layered import GRID_RES_RANGE

    one = atlas_pixels(atlas_mappings(*hw, np.eye(3)[None])[None], hw)
    return max(one, min(float(GRID_RES_RANGE[1]), frames * one))


SETTINGS = {  # the settings that size each part, named in a refusal (the alpha grid follows the frame: --resize)
    "alpha grid": (),
    "alpha MLP": (),
    "atlas grids": ("scene.grid_levels",),
    "atlas MLP": ("scene.atlas_width", "scene.atlas_depth"),
    "deformation": ("scene.deform_width", "scene.deform_depth"),
    "blur generator": ("blur.n",),
    "tone mapper and exposures": ("tone.width", "tone.depth"),
}


def _settings(cfg, keys) -> str:
    return ", ".join(f"{k}={getattr(getattr(cfg, k.split('.')[0]), k.split('.')[1])}" for k in keys)


def estimate(info: dict, cfg, task: str = "hdr-video", windows: list | None = None,
             extent: float | None = None) -> dict:
    """Peak memory and disk of a run on a clip of ``info`` (:func:`layercam.io.probe_clip`:
    ``frames``, ``width``, ``height``, ``bit_depth``) with ``cfg`` (the settings as given, a
    :class:`~layercam.core.config.Config`, or as resolved after the analysis, a
    :class:`~layercam.engine.resolve.Resolved`): ``{"memory": bytes, "disk": bytes, "stages": {stage:
    bytes}, "disk_parts": {...}, "params": {...}, "largest": str, "settings": str}``; ``largest``
    names the costliest stage or part and ``settings`` what sizes it. ``windows``: a long clip's
    windows ``[(a, b), ...]`` (``layercam.pipelines.windows``): one model of the longest window at a time
    in memory; on disk each window's masks, checkpoints and outputs, besides the joined outputs.
    ``extent``: how many frame pixels the widest window's frames span across its atlas, as the flow
    measured it (``layercam.pipelines.windows.plan.extent``); None: the widest it can be (:func:`widest_atlas`)."""
    from layercam.vision.analyse import MOTION_PAIRS
    from layercam.vision.scale import working_size
    from layercam.vision.segment import WORK_SHORT
    from layercam.vision.segment.long import SEG_FRAMES, windowed

    T = max(int(info.get("frames") or 1), 1)
    H, W = int(info["height"]), int(info["width"])
    px = H * W
    spans = [int(b) - int(a) for a, b in windows] if windows and len(windows) > 1 else [T]
    r = bound(cfg, task, T, (H, W))
    rc = r.settings
    params = model_parts(r, max(spans), (H, W), widest_atlas(max(spans), (H, W)) if extent is None else extent)
    n_params = sum(params.values())
    h, w = working_size((H, W))
    wpx = h * w
    batch = int(rc.train.batch)
    per_part = floats_per_sample(rc)
    if PARAM_BYTES * n_params < available_memory():  # a model that cannot be trained here is
                                                     # refused on its parameters alone
        fixed, per = kept_for_backward(r)
    else:
        fixed, per = 0.0, 0.0
    sample = GRAD_FACTOR * per
    stages = {
        "flow": FLOW_PER_PX * wpx + 24.0 * px if T > 1 else 0.0,
        "analysis": ANALYSIS_PER_PX * min(T - 1, MOTION_PAIRS) * wpx,
        "bootstrap": (BOOT_PER_PX * px if rc.model.layers == 1 else SEG_PER_PX * T * wpx + 16.0 * px
                      if not windowed(T, (H, W), (h, w))
                      else SEG_WORK_PER_PX * min(T, SEG_FRAMES)
                      * math.prod(working_size((h, w), WORK_SHORT)) + 16.0 * px),
                      # windows at the finder's size
        "train": PARAM_BYTES * n_params + GRAD_FACTOR * fixed + sample * batch,
        "export": 4.0 * n_params + EXPORT_FIXED + EXPORT_PER_PX * px
        + RENDER_SHARE * per * RENDER_CHUNK,  # the atlases render whole chunks at any frame size
    }
    store = 1 if int(info.get("bit_depth") or 8) <= 8 else (2 if int(info.get("bit_depth")) <= 16 else 4)
    disk = {
        "frames": float(T) * px * 3 * store,
        "flow": float(max(T - 1, 0)) * wpx * 11,
        "masks": float(sum(spans)) * px if rc.model.layers > 1 else 0.0,
        "checkpoints": 16.0 * n_params * len(spans),
        "outputs": float(T + (sum(spans) if len(spans) > 1 else 0)) * px * (6 * 0.6 + (1 if rc.model.layers > 1 else 0))
        + (float(T) * px * 3 * 5 if task == "deblur-video" else 0.0),
    }
    stage = max(stages, key=stages.get)
    if stage == "train" and PARAM_BYTES * n_params >= sample * batch:
        part = max(params, key=params.get)
        largest = f"training the model's {n_params:,} parameters ({params[part]:,} in the {part})"
        settings = _settings(rc, SETTINGS[part]) or "--resize"
    elif stage == "train":
        part = max(per_part, key=per_part.get)
        largest = f"training on batches of {batch:,} samples ({_fmt(sample * batch)}, most through the {part})"
        settings = ", ".join(filter(None, [f"train.batch={rc.train.batch}", _settings(rc, SETTINGS[part])]))
    else:
        largest = f"the {stage} stage on {W}x{H} frames"
        settings = "--resize"
    return {"memory": BASE + max(stages.values()), "disk": sum(disk.values()),
            "stages": {k: round(v) for k, v in stages.items()},
            "disk_parts": {k: round(v) for k, v in disk.items()}, "params": params,
            "largest": largest, "settings": settings,
            "frames": T, "size": [W, H], "windows": len(spans),
            "assumed": {"layers": rc.model.layers,
                        "blur": "off" if rc.model.blur == "off" else f"{rc.blur.n}x{rc.blur.n}"}}


def available_memory() -> float:
    """``MemAvailable`` (bytes; Linux), else the physical memory, else infinity."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return math.inf


def free_disk(folder: Path) -> float:
    """Free bytes where ``folder`` is (or would be made: its nearest existing parent)."""
    p = Path(folder).absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    try:
        return float(shutil.disk_usage(p).free)
    except OSError:
        return math.inf


def disk_used(folder: Path) -> float:
    """Bytes the files under ``folder`` occupy on disk (allocated blocks: a sparse file counts what
    it holds), 0 when it does not exist."""
    total = 0
    for root, _, files in os.walk(folder):
        for f in files:
            try:
                total += os.lstat(os.path.join(root, f)).st_blocks * 512
            except OSError:
                pass
    return float(total)


def summary_line(est: dict) -> str:
    """One line for the run's printout: ``estimate: peak memory 2.1 GB (train), disk 1.3 GB``."""
    stage = max(est["stages"], key=est["stages"].get)
    win = f" in {est['windows']} windows" if est.get("windows", 1) > 1 else ""
    return (f"estimate: peak memory {_fmt(est['memory'])} ({stage}), disk {_fmt(est['disk'])} for "
            f"{est['frames']} frames {est['size'][0]}x{est['size'][1]}{win}")


def check(est: dict, run_dir: Path, used_disk: float = 0.0) -> None:
    """Refuses (one line) an estimate that does not fit: memory above what is available, disk above
    what is free where the run folder is (less ``used_disk``, what the run already holds there)."""
    mem, have = est["memory"], available_memory()
    if mem > have:
        raise LayercamError(f"this run needs about {_fmt(mem)} of memory, {_fmt(have)} is "
                            f"available: most for {est['largest']}; "
                            f"lower {est['settings']}{' or --resize' if est['settings'] != '--resize' else ''}")
    need, free = est["disk"] - used_disk, free_disk(run_dir)
    if need > free:
        big = max(est["disk_parts"], key=est["disk_parts"].get)
        raise LayercamError(f"this run needs about {_fmt(est['disk'])} of disk in {run_dir}, "
                            f"{_fmt(free)} is free (most for the {big}); "
                            f"free some space, or use --resize, --max-frames or --stride")
