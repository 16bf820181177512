"""``layercam bench``: measure the speed/quality trade of the presets on scenes with ground truth."""

from __future__ import annotations

import argparse
from pathlib import Path

from layercam.cli import POSITIVE_INT


def register(sub) -> argparse.ArgumentParser:
    b = sub.add_parser("bench", help="presets x synthetic scenes (+ classical baselines) -> bench.csv, bench.png", description="Runs each preset on synthetic scenes with ground truth, and the classical baselines, on this machine. Writes bench.csv (scene, method, preset, wall s, steps/s, PSNR-mu, SSIM, peak memory), bench.png (quality against wall time, log time axis) and speedups.json (time to reach the paper preset's quality).")
    b.add_argument("--out", default="runs/bench", help="output folder (default: runs/bench)")
    b.add_argument("--scenes", default="pan", help="comma-separated scene names (default: pan)")
    b.add_argument("--presets", default="fast,balanced,quality,paper", help="comma-separated presets")
    b.add_argument("--quick", action="store_true", help="tiny scenes and a few steps: a smoke test, not a measurement")
    b.add_argument("--threads", type=POSITIVE_INT, default=2, help="torch threads per job")
    b.add_argument("--table", choices=["presets", "analysis"], default="presets", help="presets: the speed/quality trade (default); analysis: the analysed model against the full model on each synthetic family")
    b.add_argument("--preset", default="fast", help="preset for --table analysis (default: fast)")
    b.add_argument("--quiet", action="store_true")
    return b


def run(args) -> int:
    from layercam.bench import run_analysis_table, run_bench

    if args.table == "analysis":
        rows = run_analysis_table(Path(args.out), args.preset, args.quick, progress=not args.quiet)
        if not args.quiet:
            print(f"wrote {Path(args.out) / 'analysis_table.md'} ({len(rows)} rows)")
        return 0

    rows = run_bench(Path(args.out), [s for s in args.scenes.split(",") if s], [p for p in args.presets.split(",") if p], quick=args.quick, progress=not args.quiet, threads=args.threads)
    if not args.quiet:
        print(f"wrote {Path(args.out) / 'bench.csv'} and bench.png ({len(rows)} rows)")
    return 0
