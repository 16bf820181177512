"""Tasks as ordered stages. One runner, one trainer, one exporter serve every task."""

from __future__ import annotations

import platform
import time
from pathlib import Path

from layercam import analyse
from layercam.pipelines.runner import Context, run_stages, write_json
from layercam.pipelines.stages import BootstrapStage, ExportStage, FlowStage, TrainStage


def stages_for(task: str) -> list:
    return [FlowStage(), BootstrapStage(), TrainStage(), ExportStage()]


def run_task(task: str, clip, exposures, cfg, run_dir: Path, overrides: dict | None = None, masks=None, progress: bool = True, extra: dict | None = None, extra_stages: list | None = None) -> Context:
    """Analyse ``clip``, run the task's stages into ``run_dir`` and write ``report.json``."""
    t0 = time.perf_counter()
    spec = analyse.decide(clip, exposures, task, overrides, cfg)
    ctx = Context(run_dir=Path(run_dir), clip=clip, exposures=exposures, cfg=cfg, spec=spec, task=task, masks=masks, progress=progress, extra=extra or {})
    ctx.say(f"layercam {task}: {clip.T} frames {clip.W}x{clip.H} from {clip.source}; preset {cfg.preset}")
    ctx.say("model chosen:\n" + analyse.format_table(spec))
    run_stages(ctx, stages_for(task) + list(extra_stages or []))
    write_report(ctx, time.perf_counter() - t0)
    return ctx


def write_report(ctx: Context, wall: float) -> dict:
    import torch

    train = dict(ctx.results.get("train", {}))
    train.pop("model_path", None)
    rep = {
        "task": ctx.task,
        "input": {"source": str(ctx.clip.source), "frames": ctx.clip.T, "width": ctx.clip.W, "height": ctx.clip.H, "fps": ctx.clip.fps, "bit_depth": ctx.clip.bit_depth},
        "exposures": {"spec": ctx.exposures.spec, "reason": ctx.exposures.reason, "log2_dt_given": ctx.exposures.log2_dt.tolist(), "learn": ctx.exposures.learn},
        "analysis": ctx.spec.to_dict(),
        "settings": ctx.cfg.to_dict(),
        "stages": ctx.times,
        "wall_seconds": round(wall, 2),
        "train": train,
        "flow": {k: v for k, v in ctx.results.get("flow", {}).items() if k != "path"},
        "export": {k: v for k, v in ctx.results.get("export", {}).items()},
        "metrics": ctx.results.get("evaluate", {}).get("metrics"),
        "baselines": ctx.results.get("evaluate", {}).get("baselines"),
        "machine": {"python": platform.python_version(), "torch": torch.__version__, "threads": torch.get_num_threads(), "cpu": platform.processor() or platform.machine()},
        "cache_keys": ctx.keys,
    }
    write_json(ctx.run_dir / "report.json", rep)
    return rep
