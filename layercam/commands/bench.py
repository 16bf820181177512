"""``layercam bench``: measure the speed/quality trade of the presets on scenes with ground truth
(``--suite synthetic``), or layercam against the classical merges on real captures (``--suite real``);
``--table`` picks the synthetic suite's other tables (the analysis, layers, scaling, length, hdr.mp4's
cost and round trip, the blur generator, window joins)."""

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
against a Robertson merge of all shots: a reference, not truth), composite-2ev, composite-3ev and
composite-still (a real person over a real radiance map, the camera panning or still, ground truth
per frame), basler (real video, flicker).
A finished job is skipped when run again (--force redoes it); writes real_suite.csv, real_suite.md
and cases/<case>/figure.png.

other tables:
  layercam bench --table hdr-video --out runs/hdr                 # hdr.mp4 on the Basler clip: cost, round trip
  layercam bench --table blur --cases shake --out runs/blur       # the blur generator on synthetic shake
  layercam bench --table blur --cases mfme-3,mfme-9 --seeds 0,1,2  # ... and on a focus x exposure stack
  layercam bench --table joins --out runs/joins                   # two windows against one model, 96 frames
  layercam bench --table finder --out runs/finder                 # the foreground finder's steps, each left out"""


SIZES_DEFAULT = "128x128,256x256,512x512,1080x1920"


def register(sub) -> argparse.ArgumentParser:
    b = sub.add_parser("bench",
                       help="presets x synthetic scenes, or the real-capture suite -> tables and "
                            "figures",
                       description="--suite synthetic (default): runs each preset on synthetic "
                                   "scenes with ground truth, and the classical baselines, on this "
                                   "machine. Writes bench.csv (scene, method, preset, wall s, "
                                   "steps/s, PSNR-mu, SSIM, peak memory), bench.png (quality "
                                   "against wall time, log time axis) and speedups.json (time to "
                                   "reach the paper preset's quality). --suite real: layercam as a "
                                   "user would run it next to OpenCV's merges on the real captures "
                                   "in ../shared/data and on composites of real material with "
                                   "ground truth.", epilog=REAL_EXAMPLES,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    b.add_argument("--suite", choices=["synthetic", "real"], default="synthetic",
                   help="synthetic scenes (default) or the real-capture suite")
    b.add_argument("--out", help="output folder (default: runs/bench, or runs/real for --suite real)")
    b.add_argument("--scenes", default="pan", help="synthetic suite: comma-separated scene names (default: pan)")
    b.add_argument("--cases",
                   help="real suite: comma-separated case names (default: all); --table blur: "
                        "shake, mfme-3, mfme-9 (the stack trained on 3 or all 9 images); --table "
                        "joins: composite, basler (default: all)")
    b.add_argument("--presets",
                   help="comma-separated presets (default: fast,balanced,quality,paper; real "
                        "suite, --table layers, finder and scaling: fast,balanced)")
    b.add_argument("--quick", action="store_true", help="tiny scenes and a few steps: a smoke test, not a measurement")
    b.add_argument("--threads", type=POSITIVE_INT,
                   help="torch threads per job (default: 2; real suite, --table hdr-video, blur, "
                        "joins: 1)")
    b.add_argument("--table",
                   choices=["presets", "analysis", "layers", "finder", "scaling", "length",
                            "hdr-video", "blur", "joins"], default="presets",
                   help="synthetic suite: presets, the speed/quality trade (default); analysis: "
                        "the analysed model against the full model on each synthetic family; "
                        "layers: alpha against the true masks on the real DAVIS clips, with and "
                        "without --masks; finder: the foreground finder's masks on the same clips "
                        "(no training) with all its steps, each left out, and none -> finder.json, "
                        ".md; scaling: cost against frame size (steps/s, stage times, peak memory, "
                        "quality) -> scaling.csv, scaling.png; length: cost against the clip's "
                        "length (peak memory sampled, the estimate, wall time) on a DAVIS clip "
                        "played forth and back -> length.csv, length.png; hdr-video: hdr.mp4's "
                        "cost and round trip per --hdr-format on the real Basler clip -> "
                        "hdr_video.json, .md, .png; blur: the blur generator's variants on "
                        "synthetic camera shake and a focus x exposure stack against ground truth "
                        "-> shake.json, mfme.json; joins: two windows against one model on "
                        "96-frame clips (a composite with truth, the Basler clip), PSNR-mu and "
                        "flicker at the join -> joins.json, .md, .png")
    b.add_argument("--lengths", default="48,192,768",
                   help="--table length: clip lengths in frames (default: 48,192,768); the clip: "
                        "the first of --clips (default cows), its size: the first of --sizes when "
                        "given (HxW, e.g. 1080x1920), else its own")
    b.add_argument("--preset",
                   help="preset for --table analysis, length, blur and joins (default: fast) and "
                        "hdr-video (default: balanced, hdr-video's own)")
    b.add_argument("--force", action="store_true",
                   help="real suite, --table layers, finder, hdr-video, joins: redo finished jobs "
                        "(hdr-video: train the run again)")
    b.add_argument("--data",
                   help="real suite, --table layers, finder, length, hdr-video, joins: the shared "
                        "captures (default: $LAYERCAM_DATA or ../shared/data)")
    b.add_argument("--max-frames", type=POSITIVE_INT,
                   help="real suite: frames of the Basler clip (default: all 74); --table layers, "
                        "finder: the first N of each clip (default: 24)")
    b.add_argument("--clips",
                   help="--table layers, finder: comma-separated clip names, e.g. libby,cows "
                        "(default: every layers_davis_* clip of --split)")
    b.add_argument("--split", choices=["validation", "training", "all"], default="validation",
                   help="--table layers, finder: the DAVIS clips of DAVIS 2016's validation split "
                        "(judged on, never fitted on; default), of its training split (where "
                        "anything learned or tuned is fitted), or all; each split is its own table")
    b.add_argument("--variants",
                   help="--table layers: motion (no masks: the motion bootstrap), masks (the true "
                        "masks given) (default: both); --table length: masks alone gives the true "
                        "masks; --table hdr-video: the --hdr-format values to export (default: "
                        "none,pq,hlg); --table blur: the blur generator's variants, s5 (3x3 patch, "
                        "offsets up to 5 px), s0 (fixed 3x3 patch), off, s5n5 (5x5 patch), s5nf "
                        "(no flow loss) (default: s5,s0,off for shake, s5,off for mfme)")
    b.add_argument("--repeat", type=POSITIVE_INT,
                   help="--table hdr-video: exports per --hdr-format, their median reported "
                        "(default: 2; --quick: 1)")
    b.add_argument("--seeds", default="0",
                   help="--table blur: comma-separated training seeds of the mfme cases, their "
                        "PSNR-mu mean and std reported (default: 0)")
    b.add_argument("--resize", default="0.33",
                   help="--table layers, finder: frame scale, as hdr-video's --resize (default: "
                        "0.33)")
    b.add_argument("--layers", choices=["auto", "2"], default="2",
                   help="--table layers: 2, forced (default: alpha is scored on every clip); auto: "
                        "the analysis decides (a clip where the finder finds no object runs with "
                        "one layer)")
    b.add_argument("--sizes",
                   help="--table scaling: frame sizes HxW (default: "
                        "128x128,256x256,512x512,1080x1920); --table blur: the scenes' size, the "
                        "first of them (default: 64x64)")
    b.add_argument("--frames", type=POSITIVE_INT,
                   help="--table scaling: frames per clip (default 48); --table blur: the shake "
                        "clip's frames (default 8); --table joins: the clips' length, cut into two "
                        "windows (default 96)")
    b.add_argument("--no-baseline", action="store_true", help="--table scaling: no flow + Debevec rows")
    b.add_argument("--redraw", action="store_true",
                   help="real suite: run nothing, write the table and figures again from the "
                        "finished jobs")
    b.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="a setting for every layercam job of the suite or table (repeatable; e.g. "
                        "train.seed=1 for a spread over training seeds)")
    b.add_argument("--quiet", action="store_true")
    b.set_defaults(bench_defaults={a.dest: a.default for a in b._actions if a.dest not in ("help",)})
    return b


def _list(s: str | None) -> list[str] | None:
    return [x for x in s.split(",") if x] if s else None


# the options each mode reads besides --out, --set, --quiet (--suite real, else its --table)
READS = {
    "real": {"cases", "presets", "max_frames", "threads", "force", "data", "redraw", "quick"},
    "presets": {"scenes", "presets", "quick", "threads"},
    "analysis": {"preset", "quick"},
    "layers": {"clips", "variants", "presets", "resize", "layers", "max_frames", "threads", "force", "data",
               "split"},
    "finder": {"clips", "presets", "resize", "max_frames", "force", "data", "split"},
    "scaling": {"sizes", "presets", "frames", "threads", "no_baseline"},
    "length": {"lengths", "clips", "sizes", "preset", "threads", "variants", "data"},
    "hdr-video": {"preset", "variants", "repeat", "force", "data", "quick", "threads"},
    "blur": {"cases", "variants", "seeds", "preset", "sizes", "frames", "quick", "threads"},
    "joins": {"cases", "preset", "frames", "force", "data", "quick", "threads"},
}


def check_options(args, parser_defaults: dict) -> None:
    """An option the chosen suite or table does not read is an error (one line), not ignored."""
    from layercam.core.errors import LayercamError

    mode = "real" if args.suite == "real" else args.table
    if mode == "real" and args.table != "presets":
        raise LayercamError(f"--suite real and --table {args.table} are two benchmarks: give one of them")
    for name, default in parser_defaults.items():
        if name in READS[mode] or name in ("suite", "table", "out", "overrides",
                                           "quiet") or getattr(args, name, default) == default:
            continue
        what = "--suite real" if mode == "real" else f"--table {mode}"
        uses = ", ".join("--" + o.replace("_", "-") for o in sorted(READS[mode]))
        raise LayercamError(f"--{name.replace('_', '-')} is not read by {what} (it reads {uses})")


def run(args) -> int:
    check_options(args, getattr(args, "bench_defaults", {}))
    if args.suite == "real":
        return _run_real(args)
    from layercam.bench.analysis import run_analysis_table
    from layercam.bench.synthetic import run_bench

    out = Path(args.out or "runs/bench")
    if args.table == "scaling":
        from layercam.bench.scaling import run_scaling

        rows = run_scaling(out, _list(args.sizes or SIZES_DEFAULT), _list(args.presets),
                           args.frames or 48, args.threads or 2, args.overrides,
                           not args.no_baseline, progress=not args.quiet)
        if not args.quiet:
            print(f"wrote {out / 'scaling.csv'} and scaling.png ({len(rows)} rows)")
        return 0
    if args.table == "length":
        from layercam.bench.length import run_length
        from layercam.bench.scaling import parse_size

        data = _data(args)
        from layercam.core.errors import LayercamError

        # given: the clip scaled to its first size
        size = parse_size(_list(args.sizes)[0])[::-1] if args.sizes else None
        try:
            lengths = [int(v) for v in _list(args.lengths) or []]
        except ValueError:
            raise LayercamError(f"--lengths: expected frame counts like 48,192,768, got {args.lengths!r}") from None
        if not lengths or min(lengths) < 2:
            raise LayercamError(f"--lengths: expected frame counts of at least 2, got {args.lengths!r}")
        rows = run_length(out if args.out else Path("runs/length"), data,
                          (_list(args.clips) or ["cows"])[0], lengths, args.preset or "fast", size,
                          args.threads or 1, args.overrides,
                          progress=not args.quiet,
                          masks="masks" in (_list(args.variants) or [])
                          and "motion" not in (_list(args.variants) or []))
        if not args.quiet:
            print(f"wrote {(out if args.out else Path('runs/length')) / 'length.csv'} and "
                  f"length.png ({len(rows)} rows)")
        return 0
    if args.table == "layers":
        from layercam.bench.layers import MAX_FRAMES, VARIANTS, run_layers_table

        data = _data(args)
        rows = run_layers_table(out, data, _list(args.clips),
                                tuple(_list(args.variants) or VARIANTS),
                                tuple(_list(args.presets) or ("fast", "balanced")), args.resize,
                                args.overrides, args.layers, args.max_frames or MAX_FRAMES,
                                args.threads or 1, args.force, progress=not args.quiet,
                                split=args.split)
        if not args.quiet:
            print(f"wrote {out / 'layers.md'} ({len(rows)} rows)")
        return 0
    if args.table == "finder":
        from layercam.bench.finder import run_finder_table

        flags = (("--clips", args.clips), ("--presets", args.presets),
                 ("--resize", args.resize if args.resize != "0.33" else None),
                 ("--max-frames", args.max_frames),
                 ("--split", args.split if args.split != "validation" else None))
        rows = run_finder_table(out, _data(args), _list(args.clips),
                                tuple(_list(args.presets) or ("fast", "balanced")), args.resize,
                                args.max_frames, args.overrides, args.force,
                                progress=not args.quiet,
                                command=_command("layercam bench --table finder", out, flags,
                                                 args.overrides), split=args.split)
        if not args.quiet:
            print(f"wrote {out / 'finder.md'} ({len(rows)} rows)")
        return 0
    if args.table in ("hdr-video", "blur", "joins"):
        return _run_moved(args)
    if args.table == "analysis":
        rows = run_analysis_table(out, args.preset or "fast", args.quick, progress=not args.quiet,
                                  overrides_cfg=args.overrides)
        if not args.quiet:
            print(f"wrote {out / 'analysis_table.md'} ({len(rows)} rows)")
        return 0

    rows = run_bench(out, _list(args.scenes) or [],
                     _list(args.presets) or ["fast", "balanced", "quality", "paper"],
                     quick=args.quick, progress=not args.quiet, threads=args.threads or 2,
                     overrides=args.overrides)
    if not args.quiet:
        print(f"wrote {out / 'bench.csv'} and bench.png ({len(rows)} rows)")
    return 0


def _data(args) -> Path:
    """The shared captures: --data, else $LAYERCAM_DATA, else ../shared/data (unchecked: each table
    says which capture it misses)."""
    import os

    return Path(args.data or os.environ.get("LAYERCAM_DATA") or "../shared/data")


def _run_moved(args) -> int:
    """--table hdr-video, blur and joins (each writes its files under --out, default runs/<table>)."""
    out = Path(args.out or f"runs/{args.table}")
    common = dict(overrides=args.overrides, quick=args.quick, threads=args.threads or 1, progress=not args.quiet)
    if args.table == "hdr-video":
        from layercam.bench.hdr_video import run_hdr_video

        rows = run_hdr_video(out, _data(args), args.preset or "balanced", _list(args.variants),
                             args.repeat or (1 if args.quick else 2), force=args.force, **common)
        wrote = f"{out / 'hdr_video.md'}, hdr_video.json and hdr_video.png ({len(rows)} exports)"
    elif args.table == "blur":
        from layercam.bench.blur import run_blur
        from layercam.bench.scaling import parse_size
        from layercam.core.errors import LayercamError

        try:
            seeds = [int(v) for v in _list(args.seeds) or [0]]
        except ValueError:
            raise LayercamError(f"--seeds: expected integers like 0,1,2, got {args.seeds!r}") from None
        size = parse_size(_list(args.sizes)[0]) if args.sizes else None
        res = run_blur(out, _list(args.cases), _list(args.variants), seeds, args.preset or "fast",
                       size=size, frames=args.frames, **common)
        wrote = " and ".join(str(out / f"{k}.json") for k in res)
    else:
        from layercam.bench.joins import run_joins

        rows = run_joins(out, _data(args), _list(args.cases), args.preset or "fast", args.frames,
                         force=args.force, **common)
        wrote = f"{out / 'joins.md'}, joins.json and joins.png ({len(rows)} clips)"
    if not args.quiet:
        print(f"wrote {wrote}")
    return 0


def _command(head: str, out: Path, flags: tuple, overrides: list[str], quick: bool = False) -> str:
    """The command line that regenerates a table: ``head``, ``--out``, each ``(flag, value)`` given, each ``--set``."""
    import shlex

    cmd = f"{head} --out {shlex.quote(str(out))}" + "".join(f" {flag} {v}" for flag, v in flags if v)
    return cmd + "".join(f" --set {s}" for s in overrides) + (" --quick" if quick else "")


def _run_real(args) -> int:
    from layercam.bench.realsuite import run_real_suite

    out = Path(args.out or "runs/real")
    picks = () if args.redraw else (("--cases", args.cases), ("--presets", args.presets))  # a redraw writes every row
    cmd = _command("layercam bench --suite real", out,
                   (*picks, ("--max-frames", args.max_frames), ("--threads", args.threads)),
                   args.overrides, args.quick)
    rows = run_real_suite(out, _list(args.cases), _list(args.presets), args.data, args.force,
                          args.quick, args.threads or 1, args.overrides, args.max_frames,
                          progress=not args.quiet, command=cmd, redraw=args.redraw)
    if not args.quiet:
        print(f"wrote {out / 'real_suite.md'}, real_suite.csv and cases/*/figure.png ({len(rows)} rows)")
    return 0
