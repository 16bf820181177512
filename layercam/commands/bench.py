"""``layercam bench``: measure the speed/quality trade of the presets on scenes with ground truth
(``--suite synthetic``), or layercam against the classical merges on real captures (``--suite real``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from layercam.cli import POSITIVE_INT

REAL_EXAMPLES = """real suite:
  layercam bench --suite real --out runs/real                       # every case, fast and balanced
  layercam bench --suite real --cases ntire-000000,composite-3ev --presets fast
  layercam bench --suite real --presets quality --out runs/real     # adds quality to the same table
  layercam bench --suite real --force --cases basler --max-frames 24

Cases: ntire-000000..000003 (brackets with ground truth), taipei-3 and frobisher (brackets scored
against a Robertson merge of all shots: a reference, not truth), composite-2ev and composite-3ev
(a real person over a real radiance map, ground truth per frame), basler (real video, flicker).
A finished job is skipped when run again (--force redoes it); writes real_suite.csv, real_suite.md
and cases/<case>/figure.png."""


SIZES_DEFAULT = "128x128,256x256,512x512,1080x1920"


def register(sub) -> argparse.ArgumentParser:
    b = sub.add_parser("bench", help="presets x synthetic scenes, or the real-capture suite -> tables and figures", description="--suite synthetic (default): runs each preset on synthetic scenes with ground truth, and the classical baselines, on this machine. Writes bench.csv (scene, method, preset, wall s, steps/s, PSNR-mu, SSIM, peak memory), bench.png (quality against wall time, log time axis) and speedups.json (time to reach the paper preset's quality). --suite real: layercam as a user would run it next to OpenCV's merges on the real captures in ../shared/data and on composites of real material with ground truth.", epilog=REAL_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    b.add_argument("--suite", choices=["synthetic", "real"], default="synthetic", help="synthetic scenes (default) or the real-capture suite")
    b.add_argument("--out", help="output folder (default: runs/bench, or runs/real for --suite real)")
    b.add_argument("--scenes", default="pan", help="synthetic suite: comma-separated scene names (default: pan)")
    b.add_argument("--cases", help="real suite: comma-separated case names (default: all)")
    b.add_argument("--presets", help="comma-separated presets (default: fast,balanced,quality,paper; real suite, --table layers and scaling: fast,balanced)")
    b.add_argument("--quick", action="store_true", help="tiny scenes and a few steps: a smoke test, not a measurement")
    b.add_argument("--threads", type=POSITIVE_INT, help="torch threads per job (default: 2; real suite: 1)")
    b.add_argument("--table", choices=["presets", "analysis", "layers", "scaling", "length"], default="presets", help="synthetic suite: presets, the speed/quality trade (default); analysis: the analysed model against the full model on each synthetic family; layers: alpha against the true masks on the real DAVIS clips, with and without --masks; scaling: cost against frame size (steps/s, stage times, peak memory, quality) -> scaling.csv, scaling.png; length: cost against the clip's length (peak memory sampled, the estimate, wall time) on a DAVIS clip played forth and back -> length.csv, length.png")
    b.add_argument("--lengths", default="48,192,768", help="--table length: clip lengths in frames (default: 48,192,768); the clip: the first of --clips (default cows), its size: the first of --sizes when given (HxW, e.g. 1080x1920), else its own")
    b.add_argument("--preset", default="fast", help="preset for --table analysis and layers (default: fast)")
    b.add_argument("--force", action="store_true", help="real suite, --table layers: redo finished jobs")
    b.add_argument("--data", help="real suite, --table layers: the shared captures (default: $LAYERCAM_DATA or ../shared/data)")
    b.add_argument("--max-frames", type=POSITIVE_INT, help="real suite: frames of the Basler clip (default: all 74); --table layers: the first N of each clip (default: 24)")
    b.add_argument("--clips", help="--table layers: comma-separated clip names, e.g. libby,cows (default: every layers_davis_* clip)")
    b.add_argument("--variants", default="motion,masks", help="--table layers: motion (no masks: the motion bootstrap), masks (the true masks given) (default: both); --table length: masks alone gives the true masks")
    b.add_argument("--resize", default="0.33", help="--table layers: frame scale, as hdr-video's --resize (default: 0.33)")
    b.add_argument("--layers", choices=["auto", "2"], default="2", help="--table layers: 2, forced (default: alpha is scored on every clip); auto: the analysis decides (a clip where the finder finds no object runs with one layer)")
    b.add_argument("--sizes", default=SIZES_DEFAULT, help="--table scaling: frame sizes HxW (default: 128x128,256x256,512x512,1080x1920)")
    b.add_argument("--frames", type=POSITIVE_INT, default=48, help="--table scaling: frames per clip (default 48)")
    b.add_argument("--no-baseline", action="store_true", help="--table scaling: no flow + Debevec rows")
    b.add_argument("--redraw", action="store_true", help="real suite: run nothing, write the table and figures again from the finished jobs")
    b.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE", help="real suite, --table layers and scaling: a setting for every layercam job (repeatable)")
    b.add_argument("--quiet", action="store_true")
    return b


def _list(s: str | None) -> list[str] | None:
    return [x for x in s.split(",") if x] if s else None


def run(args) -> int:
    if args.suite == "real":
        return _run_real(args)
    from layercam.bench.synthetic import run_analysis_table, run_bench

    out = Path(args.out or "runs/bench")
    if args.table == "scaling":
        from layercam.bench.scaling import run_scaling

        rows = run_scaling(out, _list(args.sizes), _list(args.presets), args.frames, args.threads or 2, args.overrides, not args.no_baseline, progress=not args.quiet)
        if not args.quiet:
            print(f"wrote {out / 'scaling.csv'} and scaling.png ({len(rows)} rows)")
        return 0
    if args.table == "length":
        import os

        from layercam.bench.length import run_length
        from layercam.bench.scaling import parse_size

        data = Path(args.data or os.environ.get("LAYERCAM_DATA") or "../shared/data")
        from layercam.core.errors import LayercamError

        sized = args.sizes != SIZES_DEFAULT  # given: the clip scaled to its first size
        size = parse_size(_list(args.sizes)[0])[::-1] if sized else None
        try:
            lengths = [int(v) for v in _list(args.lengths) or []]
        except ValueError:
            raise LayercamError(f"--lengths: expected frame counts like 48,192,768, got {args.lengths!r}") from None
        if not lengths or min(lengths) < 2:
            raise LayercamError(f"--lengths: expected frame counts of at least 2, got {args.lengths!r}")
        rows = run_length(out if args.out else Path("runs/length"), data, (_list(args.clips) or ["cows"])[0], lengths, args.preset, size, args.threads or 1, args.overrides,
                          progress=not args.quiet, masks="masks" in (_list(args.variants) or []) and "motion" not in (_list(args.variants) or []))
        if not args.quiet:
            print(f"wrote {(out if args.out else Path('runs/length')) / 'length.csv'} and length.png ({len(rows)} rows)")
        return 0
    if args.table == "layers":
        import os

        from layercam.bench.layers import MAX_FRAMES, run_layers_table

        data = Path(args.data or os.environ.get("LAYERCAM_DATA") or "../shared/data")
        rows = run_layers_table(out, data, _list(args.clips), tuple(_list(args.variants) or ()), tuple(_list(args.presets) or ("fast", "balanced")), args.resize, args.overrides, args.layers, args.max_frames or MAX_FRAMES, args.threads or 1, args.force, progress=not args.quiet)
        if not args.quiet:
            print(f"wrote {out / 'layers.md'} ({len(rows)} rows)")
        return 0
    if args.table == "analysis":
        rows = run_analysis_table(out, args.preset, args.quick, progress=not args.quiet)
        if not args.quiet:
            print(f"wrote {out / 'analysis_table.md'} ({len(rows)} rows)")
        return 0

    rows = run_bench(out, _list(args.scenes) or [], _list(args.presets) or ["fast", "balanced", "quality", "paper"], quick=args.quick, progress=not args.quiet, threads=args.threads or 2)
    if not args.quiet:
        print(f"wrote {out / 'bench.csv'} and bench.png ({len(rows)} rows)")
    return 0


def _run_real(args) -> int:
    import shlex

    from layercam.bench.realsuite import run_real_suite

    out = Path(args.out or "runs/real")
    cmd = "layercam bench --suite real --out " + shlex.quote(str(out))
    picks = () if args.redraw else (("--cases", args.cases), ("--presets", args.presets))  # a redraw writes every row
    for flag, v in (*picks, ("--max-frames", args.max_frames), ("--threads", args.threads)):
        if v:
            cmd += f" {flag} {v}"
    cmd += "".join(f" --set {s}" for s in args.overrides) + (" --quick" if args.quick else "")
    rows = run_real_suite(out, _list(args.cases), _list(args.presets), args.data, args.force, args.quick, args.threads or 1, args.overrides, args.max_frames, progress=not args.quiet, command=cmd, redraw=args.redraw)
    if not args.quiet:
        print(f"wrote {out / 'real_suite.md'}, real_suite.csv and cases/*/figure.png ({len(rows)} rows)")
    return 0
