"""Tasks as ordered stages. One runner, one trainer, one exporter serve every task."""

from __future__ import annotations

import dataclasses
import platform
import time
from pathlib import Path

import numpy as np

from layercam.engine import decide
from layercam.vision import analyse

from layercam.core.heap import process_peak_bytes
from layercam.engine import distributed
from layercam.core.config import validate
from layercam.engine.resolve import format_table, resolve
from layercam.core.errors import LayercamError
from layercam.io.lock import run_lock
from layercam.pipelines import publish
from layercam.pipelines.export import ExportStage
from layercam.pipelines.results import TrainResult
from layercam.pipelines.runner import Context, output_sources, run_stages, write_json
from layercam.pipelines.stages import BootstrapStage, FlowStage, TrainStage, faded_foreground


def stages_for(task: str) -> list:
    """Every task runs the same stages; the export stage picks its writers by ``task``."""
    return [FlowStage(), BootstrapStage(), TrainStage(), ExportStage()]


def run_task(task: str, clip, exposures, cfg, run_dir: Path, masks=None, progress: bool = True,
             extra_stages: list | None = None, train_callbacks: list | None = None,
             window: int | None = None, ray: str | None = None) -> Context:
    """Analyse ``clip``, run the task's stages (and ``extra_stages``, e.g. an evaluate stage) into
    ``run_dir`` and write ``report.json``. After the flow, the settings are resolved once
    (:func:`layercam.engine.resolve.resolve`: each ``auto`` decided from what the analysis measured, values
    set are kept: ``--layers`` etc.) into ``ctx.resolved``, which every later stage reads.
    ``train_callbacks``: functions of the model that return more trainer callbacks (the benchmark's
    quality probe). ``window``: a video's windows (``layercam.pipelines.windows``): None as the analysis
    decides, 0 none, N frames each; ``ray``: a Ray cluster (``auto`` or an address) that trains the
    windows (``layercam.engine.cluster``)."""
    t0 = time.perf_counter()
    validate(cfg)
    ctx = Context(run_dir=Path(run_dir), clip=clip, exposures=exposures, cfg=cfg, task=task,
                  masks=masks, progress=progress, train_callbacks=list(train_callbacks or []))
    ctx.say(f"layercam {task}: {clip.T} frames {clip.W}x{clip.H} from {clip.source}; preset {cfg.preset}")
    for w in list(getattr(exposures, "warnings", [])) + list(clip.meta.get("notes", [])):
        ctx.warn(w)
    ctx.estimate["before"] = _estimate(ctx, cfg, "")  # refused here, before any stage, when it cannot fit
    stages = stages_for(task) + list(extra_stages or [])
    if ray:
        from layercam.engine import cluster

        cluster.available()  # before any work
    evaluated = bool(extra_stages or train_callbacks)  # the demo and the benchmark score one model of the whole clip
    if evaluated and window not in (None, 0):
        raise LayercamError("--window: this command scores one model of the whole clip; leave --window out")
    with run_lock(ctx.run_dir, ctx.say, enabled=distributed.is_main()):  # one writer per run folder
        _run(ctx, stages, t0, 0 if evaluated else window, ray)
    return ctx


def _run(ctx: Context, stages: list, t0: float, window=None, ray: str | None = None) -> None:
    from layercam.pipelines.windows import plan as window_plan, run as window_run
    from layercam.pipelines.windows.join import WindowsStage

    clip, exposures, task, cfg = ctx.clip, ctx.exposures, ctx.task, ctx.cfg
    # before any work
    publish.check_folder(ctx.run_dir,
                         [n for st in stages + [WindowsStage()] for n in st.output_names(ctx)])
    extra = {}
    try:
        # flow first: the analysis reads it to decide what the model needs
        run_stages(ctx, stages[:1])
        ctx.measures = analyse.measure(clip, exposures, ctx.flow)
        ctx.measures["masks_given"] = ctx.masks is not None and any(np.asarray(m).any() for m in ctx.masks)
        ctx.resolved = resolve(cfg, clip, exposures, task, ctx.measures)
        plan = window_plan.plan(clip, exposures, ctx.flow, task, window)
        if task != "fuse-stack" and len(stages) == 4 and not ctx.train_callbacks:
            # not for a stack, nor a scored run (demo, bench)
            ctx.resolved = dataclasses.replace(ctx.resolved, reasons={**ctx.resolved.reasons, "window": plan.reason})
        if ray and plan.count == 1:
            ctx.say("[ray] one model for the whole clip: it trains here (--ray distributes a long clip's windows)")
        ctx.say("model chosen:\n" + format_table(ctx.resolved, plan.count))
        ctx.estimate["after_analysis"] = _estimate(ctx, ctx.resolved, " (the model chosen)", plan)
        if plan.count > 1:  # a long clip: windows of the stages below, then joined
            results = window_run.run_all(ctx, plan, ray)
            for r in results:
                for w in r["warnings"]:
                    ctx.warn(f"window {r['index']} (frames {r['frames'][0]}..{r['frames'][1] - 1}): {w}")
            stages = [stages[0], WindowsStage(plan, results)]
            run_stages(ctx, stages[1:])
            ctx.results["train"] = TrainResult(window_run.train_summary(results))
            runs = [{**{k: r[k] for k in ("index", "frames", "keys", "times")},
                     "folder": str(Path(r["folder"]).relative_to(ctx.run_dir))} for r in results]
            extra = {"windows": {**plan.to_dict(), "runs": runs, "ray": ctx.ray}}
        else:
            run_stages(ctx, stages[1:2])  # the bootstrap: motion masks for two layers
            unfound = decide.unfound_foreground(cfg, ctx.results["bootstrap"].foreground)
            if unfound:  # the analysis chose two layers and the finder found no object: one layer, saying why
                ctx.measures.update(foreground_found=False, foreground_reason=unfound)
                again = resolve(cfg, clip, exposures, task, ctx.measures)
                ctx.resolved = dataclasses.replace(again, reasons={**ctx.resolved.reasons, **again.reasons})
                ctx.say("model chosen again (no foreground found):\n" + format_table(ctx.resolved, plan.count))
                run_stages(ctx, stages[1:2])
            run_stages(ctx, stages[2:])
            faded = faded_foreground(ctx)
            if faded:
                ctx.warn(faded)
    except LayercamError as e:
        if getattr(e, "events", None) is not None:  # training stopped: say why in report_failed.json
            write_report(ctx, time.perf_counter() - t0, "report_failed.json",
                         {"error": str(e), "train": {"stopped": True, "events": e.events}})
        raise
    report = write_report(ctx, time.perf_counter() - t0, name=None, extra=extra)
    if distributed.is_main():  # the top of the run folder becomes this run's outputs and report, at once
        sources, keys = output_sources(ctx, stages)
        publish.publish(ctx.run_dir, sources, report, publish.set_key(keys), ctx.say)
        (ctx.run_dir / "report_failed.json").unlink(missing_ok=True)


def _estimate(ctx: Context, cfg, what: str, plan=None) -> dict:
    """:func:`layercam.engine.estimate.estimate` of this run with ``cfg`` (and the windows of ``plan`` and
    their atlas's extent as the flow measured it), said
    in one line and checked against the memory available and the disk free (less what the run
    folder's cache holds)."""
    from layercam.engine import estimate as cost
    from layercam.pipelines.windows.plan import extent

    clip = ctx.clip
    est = cost.estimate({"frames": clip.T, "width": clip.W, "height": clip.H,
                         "bit_depth": clip.bit_depth}, cfg, ctx.task,
                        windows=None if plan is None else plan.windows,
                        extent=None if plan is None else extent(clip, ctx.flow, plan.windows))
    ctx.say(cost.summary_line(est) + what)
    cost.check(est, ctx.run_dir, cost.disk_used(ctx.run_dir / "cache"))
    return {k: est[k]
            for k in ("memory", "disk", "stages", "disk_parts", "assumed",
                      "windows")} | {"params": int(sum(est["params"].values()))}


def write_report(ctx: Context, wall: float, name: str | None = "report.json", extra: dict | None = None) -> dict:
    """The run's report; written to ``RUN/name`` by rank 0 unless ``name`` is None."""
    import torch

    res = {k: r.report() for k, r in ctx.results.items()}
    rep = {
        "task": ctx.task,
        "input": {"source": str(ctx.clip.source), "frames": ctx.clip.T, "width": ctx.clip.W,
                  "height": ctx.clip.H, "fps": ctx.clip.fps, "bit_depth": ctx.clip.bit_depth,
                  **{k: ctx.clip.meta[k] for k in ("primaries", "audio", "video")
                     if k in ctx.clip.meta}},
                  # video: what the input's header says (frame rate, variable, sound)
        "exposures": {"spec": ctx.exposures.spec, "reason": ctx.exposures.reason,
                      "log2_dt_given": ctx.exposures.log2_dt.tolist(),
                      "learn": ctx.exposures.learn},
        "analysis": {**(decide.model_summary(ctx.resolved.settings) if ctx.resolved is not None
                        else {}),
                     "reasons": dict(ctx.resolved.reasons) if ctx.resolved is not None else {},
                     "measures": ctx.measures},
        "settings": ctx.resolved.to_dict() if ctx.resolved is not None else ctx.cfg.to_dict(),
        "stages": ctx.times,
        "wall_seconds": round(wall, 2),
        "train": res.get("train", {}),
        "flow": res.get("flow", {}),
        "export": res.get("export", {}),
        "metrics": res.get("evaluate", {}).get("metrics"),
        "baselines": res.get("evaluate", {}).get("baselines"),
        "machine": {"python": platform.python_version(), "torch": torch.__version__,
                    "threads": torch.get_num_threads(),
                    "cpu": platform.processor() or platform.machine()},
        "cache_keys": ctx.keys,
        "memory": {"estimate": ctx.estimate, "peak_rss_bytes": process_peak_bytes()},
        "warnings": ctx.warnings,
        **(extra or {}),
    }
    if name and distributed.is_main():  # with torch.distributed, rank 0 reports
        write_json(ctx.run_dir / name, rep)
    return rep

