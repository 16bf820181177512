"""Long clips as overlapping windows, each its own model, sharing one camera.

A clip longer than one model holds (:func:`plan`: the analysis's rule, or ``--window N``) is cut
into overlapping windows of frames. Each window is a run of the ordinary stages (bootstrap,
train, export) in its own folder ``RUN/cache/windows/<first>-<end>/``
(its own stage cache: each window resumes on its own), on its slice of the clip and of the whole
clip's flow, with the model the analysis decided once for the whole clip. The camera is learned
once: window 0 trains as a single model would, and the others start from its tone mapper (and
its learned exposure ratios, ``--exposures alt`` without ``--ev-step``) and hold them fixed, so
that every window renders through the same response curve and exposures (the train stage's key
names window 0's training, :func:`layercam.pipelines.stages.hold_camera`). Window 0 runs first; the others do not depend on
one another (``--ray``: tasks on a Ray cluster, ``layercam.engine.cluster``).

The windows' outputs are then joined by the ``windows`` stage (:class:`WindowsStage`): in the
overlap of windows ``k`` and ``k + 1`` (frames ``a_(k+1) .. b_k - 1``) each frame is the
cross-fade ``(1 - w) X_k + w X_(k+1)`` of the linear fade ``f = (t - a_(k+1) + 1) / (overlap + 1)``
weighted per pixel by each window's fit to the overlap's frames (:func:`~layercam.pipelines.windows.plan.overlap_fits`,
:meth:`Plan.weights`; kept in ``windows/fits.npz`` for ``render`` and ``edit``) of the
linear HDR (``hdr/``), the sharp frames (``frames/``, as floats before they are quantised) and the
foreground's alpha mattes (``alpha/``); the preview is tonemapped once over the joined clip. Each
window's own outputs for ``layercam render`` and ``edit`` (``checkpoint.pt``, ``atlases/``,
``psf.json``) are published under ``windows/w00/``, ... and ``windows.json`` says which frames
each window holds and how they are joined. The top of the run folder stays one set (the blend
stage's folder, published as every run's).
"""

from __future__ import annotations

import json
import math
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from layercam.core.config import config_hash
from layercam.core.errors import LayercamError
from layercam.core.interrupts import reached
from layercam.pipelines.results import FlowResult
from layercam.pipelines.runner import Context, Stage, run_stages, write_json
from layercam.pipelines.windows.plan import Plan, overlap_fits, per_pixel, rows, sub_clip, sub_exposures, sub_flow

INDEX = "windows.json"
FOLDER = "windows"  # RUN/windows/w00/: each window's checkpoint.pt, atlases/, psf.json
PER_WINDOW = ("checkpoint.pt", "atlases", "psf.json")
FITS = "fits.npz"  # RUN/windows/fits.npz: each window's fit to each overlap per pixel (w<k>_o<j>), the join's weights


@dataclass
class WindowSpec:
    """What one window's run needs (picklable: a Ray task receives it)."""

    index: int
    a: int
    b: int
    run_dir: str
    task: str
    clip: object
    exposures: object
    cfg: object
    resolved: object
    masks: object
    flow: object                    # the window's layercam.vision.flow_store.FlowArrays (views), None for one frame
    flow_key: str
    flow_summary: dict
    measures: dict
    clip_levels: object
    camera: dict | None = None
    progress: bool = False
    threads: int = 0  # torch threads in a task of its own (0: as the process has them)


def window_dir(run_dir: Path, a: int, b: int) -> Path:
    return Path(run_dir) / "cache" / "windows" / f"{a:05d}-{b:05d}"


def specs(ctx: Context, p: Plan) -> list[WindowSpec]:
    from layercam.pipelines.stages import ctx_clip_levels

    lv = ctx_clip_levels(ctx)
    out = []
    for k, (a, b) in enumerate(p.windows):
        out.append(WindowSpec(
            k, a, b, str(window_dir(ctx.run_dir, a, b)), ctx.task, sub_clip(ctx.clip, a, b), sub_exposures(ctx.exposures, a, b), ctx.cfg, ctx.resolved,
            None if ctx.masks is None else rows(ctx.masks, a, b), sub_flow(ctx.flow, a, b),
            config_hash({"flow": ctx.keys["flow"], "window": [a, b]})[:12], ctx.results["flow"].summary,
            ctx.measures, lv, progress=ctx.progress,
        ))
    return out


def run_window(spec: WindowSpec) -> dict:
    """One window's stages (bootstrap, train, export) in its own folder;
    returns what the joining stage and the report need (JSON-able)."""
    from layercam.pipelines.export import ExportStage
    from layercam.pipelines.stages import BootstrapStage, TrainStage
    from layercam.pipelines.stages import faded_foreground

    if spec.threads:
        import torch

        torch.set_num_threads(spec.threads)
    ctx = Context(run_dir=Path(spec.run_dir), clip=spec.clip, exposures=spec.exposures, cfg=spec.cfg, task=spec.task, masks=spec.masks,
                  progress=spec.progress, measures=spec.measures, resolved=spec.resolved, flow=spec.flow)
    ctx.camera, ctx.window = spec.camera, (spec.a, spec.b)
    ctx.keys["flow"] = spec.flow_key
    ctx.results["flow"] = FlowResult(dict(spec.flow_summary))
    ctx.clip_levels = spec.clip_levels
    ctx.say(f"[window {spec.index}] frames {spec.a}..{spec.b - 1} in {ctx.run_dir}")
    run_stages(ctx, [BootstrapStage()])
    run_stages(ctx, [TrainStage(), ExportStage()])
    faded = faded_foreground(ctx)
    return {
        "index": spec.index, "frames": [spec.a, spec.b], "folder": spec.run_dir,
        "keys": dict(ctx.keys), "dirs": {k: str(v) for k, v in ctx.dirs.items()}, "times": ctx.times,
        "train": ctx.results["train"].report(), "export": ctx.results["export"].report(),
        "warnings": list(ctx.warnings) + ([faded] if faded else []), "static": ctx.results["bootstrap"].static,
    }


# -- the shared camera ---------------------------------------------------------------------------------
def camera_from(result: dict, learn: str) -> dict:
    """Window 0's camera from its training's final checkpoint: the tone mapper's parameters and,
    where the exposures are learned per phase, their offsets. ``key``: window 0's training."""
    import torch

    state = torch.load(Path(result["dirs"]["train"]) / "ckpt.pt", map_location="cpu", weights_only=False)["model"]
    keep = {k: v for k, v in state.items() if k.startswith("tone.") or (learn == "ratio" and k == "exposure.delta")}
    return {"state": keep, "key": result["keys"]["train"]}


# -- all windows ----------------------------------------------------------------------------------------
def run_all(ctx: Context, p: Plan, ray: str | None = None) -> list[dict]:
    """Window 0, then the others (in sequence, or as Ray tasks with ``ray``), each with window 0's
    camera. Returns each window's :func:`run_window` summary, in order."""
    todo = specs(ctx, p)
    runner = None
    if ray:
        from layercam.engine import cluster

        runner = cluster.Runner(ray, ctx.say)
        ctx.ray = runner.describe
        from layercam.io.frames import TempArray

        for s in todo:
            s.progress, s.threads = False, runner.threads
            if isinstance(s.masks, TempArray):  # an unlinked file no other process can open: the window's masks sent as they are
                s.masks = np.asarray(s.masks)
    first = runner.map(_in_turn, todo[:1])[0] if runner else _in_turn(todo[0])
    camera = camera_from(first, ctx.exposures.learn) if ctx.resolved.settings.model.tone_mapper == "learned" else None
    for s in todo[1:]:
        s.camera = camera
    rest = runner.map(_in_turn, todo[1:]) if runner else [_in_turn(s) for s in todo[1:]]
    return [first, *rest]


def _in_turn(spec: WindowSpec) -> dict:
    """:func:`run_window`, then what it freed given back (its objects' cycles collected, the heap
    trimmed), so that the memory held does not grow window after window in this process or in a
    Ray worker that runs several windows."""
    from layercam.core.heap import give_back_freed_memory

    out = run_window(spec)
    give_back_freed_memory()
    return out


def train_summary(results: list[dict]) -> dict:
    """The report's ``train``: each window's, and their steps together."""
    tr = [r["train"] for r in results]
    return {"steps": int(sum(t.get("steps", 0) for t in tr)), "windows": tr, "final_loss": None, "resumed_from": [t.get("resumed_from") for t in tr]}


# -- joining --------------------------------------------------------------------------------------------
class WindowsStage(Stage):
    """Joins the windows' outputs into the clip's (this module's docstring)."""

    name = "windows"
    deps = ("flow",)

    def __init__(self, plan: Plan | None = None, results: list[dict] | None = None):
        self.plan, self.results = plan, results or []

    def output_names(self, ctx):
        from layercam.pipelines.export import TASK_WRITERS, WRITERS

        names = [n for w in TASK_WRITERS.get(ctx.task, TASK_WRITERS["hdr-video"]) for n in WRITERS[w][1]]
        return list(dict.fromkeys(names + ["alpha", "crf.json", "crf.png", FOLDER, INDEX]))

    reads = ("export.half", "task")

    def options(self, ctx):
        return {"plan": self.plan.to_dict()["windows"], "exports": [r["keys"]["export"] for r in self.results]}

    def run(self, ctx, out):
        from layercam.pipelines.export_context import exposures_vary

        p, res = self.plan, self.results
        dirs = [Path(r["dirs"]["export"]) for r in res]
        summary: dict = {"windows": p.count}
        gains = self._gains(ctx, dirs)
        p.fits = overlap_fits(p, dirs)  # each window's fit to the frames it shares, per pixel: the join's weights
        if (dirs[0] / "hdr").is_dir() and ctx.task != "deblur-video":
            summary.update(self._hdr(ctx, out, dirs, gains))
        if ctx.task == "deblur-video":
            summary.update(self._sharp(ctx, out, dirs, gains, exposures_vary(ctx)))
        if (dirs[0] / "alpha").is_dir():
            self._alpha(ctx, out, dirs)
        for n in ("crf.json", "crf.png"):
            if (dirs[0] / n).exists():
                _link(dirs[0] / n, out / n)
        for k, d in enumerate(dirs):
            sub = out / FOLDER / f"w{k:02d}"
            sub.mkdir(parents=True, exist_ok=True)
            for n in PER_WINDOW:
                if (d / n).exists():
                    _link(d / n, sub / n)
        if p.fits:
            with open(out / FOLDER / FITS, "wb") as f:
                np.savez(f, **{f"w{k}_o{j}": e for (k, j), e in p.fits.items()})
        write_json(out / INDEX, {
            "frames": ctx.clip.T,
            "windows": [{"index": k, "frames": list(p.windows[k]), "folder": f"{FOLDER}/w{k:02d}", "hdr_gain": gains[k]} for k in range(p.count)],
            "overlaps": p.overlaps(), "reason": p.reason,
            "camera": "learned by window 0, held fixed in the others" if ctx.resolved.settings.model.tone_mapper == "learned" else "the fixed sRGB curve",
            "join": f"cross-fade over each overlap weighted per pixel by each window's fit: frame t of the overlap [a, b) of windows k and k+1 is (1 - w) x_k + w x_(k+1), w = q_(k+1) / (q_k + q_(k+1)), q_k = (1 - f) / e_k, q_(k+1) = f / e_(k+1), f = (t - a + 1) / (b - a + 1), e the window's squared error per pixel over the overlap's frames (its model through its camera against the input frames; {FOLDER}/{FITS}: e_k of overlap j as w<k>_o<j>; without them the plain fade), in linear HDR (hdr/), sharp frames (frames/) and alpha (alpha/)",
        })
        summary["hdr_gains"] = gains
        return summary

    def _gains(self, ctx, dirs: list[Path]) -> list[float]:
        """Window ``k``'s HDR scale relative to window 0's. 1 where the camera is shared (given
        exposures, or learned per phase: window 0's held in the others). Exposures learned per frame
        fix each window's first frame instead, so a window's irradiance may differ from its
        neighbour's by one factor: the median ratio over their overlap (chained from window 0)."""
        gains = [1.0] * self.plan.count
        if ctx.exposures.learn != "all" or not (dirs[0] / "hdr").is_dir():
            return gains
        from layercam.io import read_exr

        for k in range(1, self.plan.count):
            a, b = self.plan.windows[k][0], self.plan.windows[k - 1][1]
            pa, pb = self.plan.windows[k - 1][0], a
            r = []
            for t in range(a, b):
                x = read_exr(dirs[k - 1] / "hdr" / f"frame_{t - pa:05d}.exr")
                y = read_exr(dirs[k] / "hdr" / f"frame_{t - pb:05d}.exr")
                ok = (x > 0) & (y > 0)
                r.append(np.log(x[ok] / y[ok]))
            gains[k] = float(gains[k - 1] * np.exp(np.median(np.concatenate(r)))) if r else gains[k - 1]
        return gains

    def _frames(self, ctx, dirs, gains, read):
        """Each frame of the clip joined: ``(t, sum_k w_k * gain_k * read(dir_k, t - a_k))``, ``w_k``
        per pixel where the plan has the windows' fits (:meth:`Plan.weights`)."""
        for t in range(ctx.clip.T):
            reached("windows", t)
            acc = None
            for k, w in self.plan.weights(t, (ctx.clip.H, ctx.clip.W)):
                x = read(dirs[k], t - self.plan.windows[k][0])
                x = x * per_pixel(np.float32(w * gains[k]), x)
                acc = x if acc is None else acc + x
            yield t, acc

    def _hdr(self, ctx, out, dirs, gains) -> dict:
        from layercam.scene import render
        from layercam.core.colour import REC709, luma
        from layercam.io import VideoWriter, read_exr
        from layercam.pipelines.export import FIRST_PASS_PIXELS
        from layercam.pipelines.export_context import _fps
        from layercam.io.hdr_set import HALF_MAX, HdrSet

        def read(d, i):
            return read_exr(d / "hdr" / f"frame_{i:05d}.exr")

        H, W = ctx.clip.H, ctx.clip.W
        step = max(1, int(math.ceil(math.sqrt(H * W / FIRST_PASS_PIXELS))))
        lum, peak = [], 0.0
        for _, hdr in self._frames(ctx, dirs, gains, read):  # the preview's statistics over the joined clip
            lum.append(luma(hdr[::step, ::step], REC709).ravel())
            peak = max(peak, float(hdr.max()))
        stats = render.display_stats(np.concatenate(lum))
        exrs = HdrSet(ctx.resolved.settings.export.half and peak <= HALF_MAX, ctx.say)
        (out / "hdr").mkdir(exist_ok=True)
        with VideoWriter(out / "preview.mp4", fps=_fps(ctx)) as preview:
            for t, hdr in self._frames(ctx, dirs, gains, read):
                exrs.add(out / "hdr" / f"frame_{t:05d}.exr", hdr)
                preview.add(render.tonemap_display(hdr, stats)[0])
        return {"frames": ctx.clip.T, "hdr_min": exrs.lo, "hdr_max": exrs.hi, "exr": "half" if exrs.half else "float32", "display": stats}

    def _sharp(self, ctx, out, dirs, gains, with_hdr: bool) -> dict:
        from layercam.io import VideoWriter, read_exr, write_png
        from layercam.pipelines.export_context import _bits, _fps
        from layercam.io.hdr_set import HdrSet

        sharp = [np.load(d / "deblurred.npy", mmap_mode="r") for d in dirs]
        T, hw = ctx.clip.T, (ctx.clip.H, ctx.clip.W)
        (out / "frames").mkdir(exist_ok=True)
        kept = np.lib.format.open_memmap(out / "deblurred.npy", mode="w+", dtype=np.float32, shape=(T, *hw, 3))
        index = {d: k for k, d in enumerate(dirs)}
        with VideoWriter(out / "deblurred.mp4", fps=_fps(ctx)) as video:
            for t, ldr in self._frames(ctx, dirs, [1.0] * len(dirs), lambda d, i: np.asarray(sharp[index[d]][i], np.float32)):
                ldr = np.clip(ldr, 0.0, 1.0)
                write_png(out / "frames" / f"frame_{t:05d}.png", ldr, bit_depth=_bits(ctx))
                kept[t] = ldr
                video.add(ldr)
        kept.flush()
        del kept, sharp
        res = {"frames": int(T), "hdr": with_hdr, "png_bits": _bits(ctx)}
        if with_hdr:
            exrs = HdrSet(ctx.resolved.settings.export.half, ctx.say)
            (out / "hdr").mkdir(exist_ok=True)
            for t, hdr in self._frames(ctx, dirs, gains, lambda d, i: read_exr(d / "hdr" / f"frame_{i:05d}.exr")):
                exrs.add(out / "hdr" / f"frame_{t:05d}.exr", hdr)
            res["hdr_max"] = exrs.hi
        return res

    def _alpha(self, ctx, out, dirs) -> None:
        from layercam.io import read_image, write_png

        (out / "alpha").mkdir(exist_ok=True)
        for t, a in self._frames(ctx, dirs, [1.0] * len(dirs), lambda d, i: read_image(d / "alpha" / f"frame_{i:05d}.png")[..., 0]):
            write_png(out / "alpha" / f"frame_{t:05d}.png", np.clip(a, 0.0, 1.0))

    def load(self, ctx, out, summary):
        from layercam.pipelines.export import kept_arrays
        from layercam.pipelines.results import ExportResult

        return ExportResult(summary, **kept_arrays(out))


def _link(src: Path, dst: Path) -> None:
    """``dst`` a hard-linked copy of ``src`` (file or folder; copies where links fail)."""
    from layercam.pipelines.publish import _link_or_copy

    if dst.is_dir():
        shutil.rmtree(dst)
    elif dst.exists():
        dst.unlink()
    if src.is_dir():
        shutil.copytree(src, dst, copy_function=_link_or_copy)
    else:
        _link_or_copy(str(src), str(dst))


# -- reading a windowed run (render, edit) -------------------------------------------------------------
def read_index(run: Path) -> dict | None:
    """A published run's ``windows.json`` (None for a run of one model)."""
    p = Path(run) / INDEX
    if not p.is_file():
        return None
    try:
        return json.loads(p.read_text())
    except (OSError, ValueError):
        raise LayercamError(f"{p} is unreadable") from None


def index_plan(index: dict, run: Path | None = None) -> Plan:
    """The plan a published run was joined with (its windows and, from ``run``'s ``windows/fits.npz``,
    their fits to the overlaps)."""
    fits = {}
    path = Path(run) / FOLDER / FITS if run is not None else None
    if path is not None and path.is_file():
        with np.load(path) as z:
            fits = {tuple(int(v) for v in n[1:].split("_o")): z[n] for n in z.files}
    return Plan([tuple(w["frames"]) for w in index["windows"]], index.get("reason", ""), fits=fits)


def window_folders(run: Path, index: dict) -> list[Path]:
    return [Path(run) / w["folder"] for w in index["windows"]]


def index_gains(index: dict) -> list[float]:
    """Each window's HDR scale relative to window 0's (``hdr_gain``: 1 where the camera is shared)."""
    return [float(w.get("hdr_gain", 1.0)) for w in index["windows"]]


def clip_reference(models, gains: list[float] | None = None) -> float:
    """The clip's reference exposure over windows (each frame once), in window 0's scale: the
    median of every frame's log2 exposure, as ``ExposureField.reference`` is for a single model.
    A window whose irradiance is ``gain`` times window 0's sees its frames at ``log2 gain`` more."""
    gains = gains or [1.0] * len(models)
    vals = [m.exposure.values().detach().float().cpu().numpy() + np.log2(g) for m, g in zip(models, gains)]
    return float(np.median(np.concatenate(vals)))
