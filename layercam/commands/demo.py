"""``layercam demo``: hdr-video on a built-in synthetic clip, scored against its ground truth."""

from __future__ import annotations

import argparse
from pathlib import Path

from layercam.cli import common_model_args, load_cfg, number


def register(sub) -> argparse.ArgumentParser:
    d = sub.add_parser("demo", help="run hdr-video on a built-in synthetic clip and score it against ground truth")
    d.add_argument("--out", default="runs/demo", help="run folder (default: runs/demo)")
    d.add_argument("--frames", type=number(int, 2), default=24)
    d.add_argument("--size", type=number(int, 8), default=128, help="frame height and width")
    d.add_argument("--ev-step", type=number(float, 0, strict=True, high=12), default=3.0)
    common_model_args(d)
    return d


def run(args) -> int:
    import numpy as np

    from layercam import synth
    from layercam.io import Exposures
    from layercam.bench.evaluate import EvaluateStage
    from layercam.pipelines.tasks import run_task

    cfg = load_cfg(args)
    scene = synth.pan_hdr(frames=args.frames, size=(args.size, args.size), ev_step=args.ev_step, seed=0)
    log2 = np.log2(scene.exposure_times / scene.exposure_times.min())
    phase = (np.arange(len(log2)) % 2).astype(np.int64)
    exposures = Exposures(log2, "none", phase, f"alt (ev-step {args.ev_step}, known)",
                          f"synthetic: exposures alternate by {args.ev_step} EV")
    ctx = run_task("demo", scene.clip, exposures, cfg, Path(args.out), progress=not args.quiet,
                   extra_stages=[EvaluateStage(scene)])
    ev = ctx.results["evaluate"]
    rows = [("layercam (" + cfg.preset + ")", ev.metrics)] + list(ev.baselines.items())
    print("\nHDR against ground truth (one scale per channel aligned):")
    print(f"  {'method':<22} {'PSNR-mu':>8} {'PSNR-L':>8} {'SSIM-mu':>8} {'wall s':>8}")
    for name, m in rows:
        print(f"  {name:<22} {m['psnr_mu']:>8.2f} {m['psnr_l']:>8.2f} {m['ssim_mu']:>8.3f} "
              f"{m.get('wall_s', float('nan')):>8.1f}")
    print(f"outputs: {ctx.run_dir}")
    return 0


