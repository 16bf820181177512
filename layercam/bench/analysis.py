"""``layercam bench --table analysis``: for each synthetic family, the model the analysis chose
against the full model forced on the same clip (the analysis models only what the scene requires):
``analysis_table.json`` and ``analysis_table.md``."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from layercam.bench.synthetic import scene_exposures

ANALYSIS_FAMILIES = {
    # name: (synth family, kwargs, quick kwargs, task)
    "static": ("static_single", {"frames": 8, "size": (64, 64)}, {"frames": 3, "size": (24, 24)}, "hdr-video"),
    "pan": ("pan_hdr", {"frames": 12, "size": (96, 96)}, {"frames": 4, "size": (24, 24)}, "hdr-video"),
    "moving": ("moving_object", {"frames": 12, "size": (96, 96)}, {"frames": 4, "size": (32, 32)}, "hdr-video"),
    "shake": ("shake_blur", {"frames": 10, "size": (96, 96)}, {"frames": 3, "size": (48, 48)},
              "deblur-video"),  # 48 px: smaller frames have too few tiles to compare sharpness
    "mfme": ("mfme_stack", {"size": (96, 96)}, {"size": (24, 24)}, "fuse-stack"),
}
FULL_MODEL = {"layers": 2, "tone_mapper": "learned", "blur": "3x3", "max_offset": 5.0,
              "flow_loss": True}  # the paper's (n = 3, s = 5); presets.model_overrides


def analysis_job(name: str, variant: str, out: Path, preset: str, quick: bool, overrides_cfg: list[str]) -> dict:
    """Train ``name`` with the analysed model (variant "chosen") or the full model ("full")."""
    from layercam import synth
    from layercam.engine.decide import model_summary
    from layercam.core.presets import load_config, model_overrides
    from layercam.bench.evaluate import EvaluateStage
    from layercam.pipelines.tasks import run_task

    fam, kw, qkw, task = ANALYSIS_FAMILIES[name]
    scene = getattr(synth, fam)(**(qkw if quick else kw))
    cfg = load_config(preset, (model_overrides(**FULL_MODEL) if variant == "full" else []) + list(overrides_cfg))
    extra = {}
    if task == "fuse-stack":
        extra.update(focus_index=np.asarray(scene.meta["focus_index"]), times=np.asarray(scene.exposure_times))
    t0 = time.perf_counter()
    ctx = run_task(task, scene.clip, scene_exposures(scene), cfg, out / name / variant,
                   progress=False, extra_stages=[EvaluateStage(scene, baselines=(), **extra)])
    wall = sum(v["seconds"] for k, v in ctx.times.items() if k != "evaluate")
    m = ctx.results["evaluate"].metrics
    metric, value = ("psnr_mu", m["psnr_mu"]) if "psnr_mu" in m else ("psnr", m["psnr"])
    return {"family": name, "variant": variant, **model_summary(ctx.resolved.settings),
            "metric": metric, "value": round(float(value), 2), "wall_s": round(wall, 1),
            "total_s": round(time.perf_counter() - t0, 1), "reasons": dict(ctx.resolved.reasons)}


def run_analysis_table(out: Path, preset: str = "fast", quick: bool = False,
                       families: list[str] | None = None, progress: bool = True,
                       overrides_cfg: list[str] | None = None) -> list[dict]:
    """For each synthetic family: the analysed model against the full model forced on the same clip."""
    from layercam.io.atomic import ensure_writable_dir

    out = ensure_writable_dir(out)
    ov = list(overrides_cfg or []) + (["train.steps=20", "train.bootstrap_steps=2", "train.batch=512"] if quick else [])
    rows = []
    for name in families or list(ANALYSIS_FAMILIES):
        for variant in ("chosen", "full"):
            r = analysis_job(name, variant, out, preset, quick, ov)
            rows.append(r)
            if progress:
                print(f"{name:>7} {variant:>6}: layers {r['layers']} tone {r['tone_mapper']:<7} "
                      f"blur {r['blur']:<4} flow {str(r['flow_loss']):<5} {r['metric']} "
                      f"{r['value']:6.2f}  {r['wall_s']:6.1f} s")
    write_analysis_table(out, rows)
    return rows


def write_analysis_table(out: Path, rows: list[dict]) -> None:
    """``analysis_table.json`` and the markdown table ``analysis_table.md``."""
    from layercam.io.atomic import atomic_write

    def text(path: Path, body: str) -> None:
        atomic_write(path, lambda p: p.write_text(body))

    text(out / "analysis_table.json", json.dumps(rows, indent=1))
    md = ["| scene | model | layers | tone mapper | blur (s) | flow loss | quality | wall s |",
          "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        blur = "off" if r["blur"] == "off" else f"{r['blur']} ({r['max_offset']:g})"
        md.append(f"| {r['family']} | {r['variant']} | {r['layers']} | {r['tone_mapper']} | {blur} "
                  f"| {'on' if r['flow_loss'] else 'off'} | {r['metric']} {r['value']:.2f} | "
                  f"{r['wall_s']:.1f} |")
    text(out / "analysis_table.md", "\n".join(md) + "\n")
