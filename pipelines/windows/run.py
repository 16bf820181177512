"""Each window of a long clip run as the ordinary stages (bootstrap, train, export) in its own
folder, window 0 first and the others with its camera held fixed (in sequence, or as Ray tasks)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from layercam.core.config import config_hash
from layercam.pipelines.results import FlowResult
from layercam.pipelines.runner import Context, run_stages
from layercam.pipelines.windows.plan import Plan, rows, sub_clip, sub_exposures, sub_flow


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
            k, a, b, str(window_dir(ctx.run_dir, a, b)), ctx.task, sub_clip(ctx.clip, a, b),
            sub_exposures(ctx.exposures, a, b), ctx.cfg, ctx.resolved,
            None if ctx.masks is None else rows(ctx.masks, a, b), sub_flow(ctx.flow, a, b),
            config_hash({"flow": ctx.keys["flow"], "window": [a, b]})[:12], ctx.results["flow"].summary,
            ctx.measures, lv, progress=ctx.progress,
        ))
    return out


def run_window(spec: WindowSpec) -> dict:
    """One window's stages (bootstrap, train, export) in its own folder;
    returns what the joining stage and the report need (JSON-able)."""
    from layercam.pipelines.export import ExportStage
    from layercam.pipelines.stages import BootstrapStage, TrainStage, faded_foreground

    if spec.threads:
        import torch

        torch.set_num_threads(spec.threads)
    ctx = Context(run_dir=Path(spec.run_dir), clip=spec.clip, exposures=spec.exposures,
                  cfg=spec.cfg, task=spec.task, masks=spec.masks,
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


def camera_from(result: dict, learn: str) -> dict:
    """Window 0's camera from its training's final checkpoint: the tone mapper's parameters and,
    where the exposures are learned per phase, their offsets. ``key``: window 0's training."""
    import torch

    state = torch.load(Path(result["dirs"]["train"]) / "ckpt.pt", map_location="cpu", weights_only=False)["model"]
    keep = {k: v for k, v in state.items() if k.startswith("tone.") or (learn == "ratio" and k == "exposure.delta")}
    return {"state": keep, "key": result["keys"]["train"]}


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
            if isinstance(s.masks, TempArray):  # an unlinked file no other process can open: the
                                                # window's masks sent as they are
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
    return {"steps": int(sum(t.get("steps", 0) for t in tr)), "windows": tr, "final_loss": None,
            "resumed_from": [t.get("resumed_from") for t in tr]}
