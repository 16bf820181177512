"""``layercam fuse-stack``: a multi-focus and/or multi-exposure photo stack -> all-in-focus linear HDR."""

from __future__ import annotations

import argparse
from pathlib import Path

from layercam.core.presets import settings_help
from layercam.cli import common_model_args, default_out, finish, load_cfg

EXAMPLES = """examples:
  layercam fuse-stack near.tif far.tif --out runs/pair                  # multi-focus (MF): sRGB assumed
  layercam fuse-stack stack/ --exposures times.txt --out runs/mfme      # multi-focus multi-exposure
  layercam fuse-stack a.jpg b.jpg c.jpg --exposures exif --reference first

The images may be unaligned (hand-held, focus breathing): they are registered by optical flow and
homographies, and the fused image is the scene seen from the reference image's view."""


def register(sub) -> argparse.ArgumentParser:
    f = sub.add_parser(
        "fuse-stack",
        help="multi-focus / multi-exposure photo stack -> all-in-focus linear HDR (fused.exr, fused.png)",
        description=(
            "Fits one scene to a stack of photos taken with different focus and/or exposure, the blur "
            "generator explaining each photo's defocus and the tone mapper its exposure, then renders the "
            "scene with the camera dropped: fused.exr (all-in-focus linear HDR), fused.png (tonemapped; for "
            "a single-exposure stack the sharp image in the input's tonality), crf.json/png, psf.json, "
            "report.json, checkpoint.pt (for layercam render)."
        ),
        epilog=EXAMPLES + "\n\n" + settings_help(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    f.add_argument("inputs", nargs="+", metavar="IMAGES", help="two or more image files, or one folder of images")
    f.add_argument("--out", help="run folder (default: runs/<first image name>)")
    g = f.add_argument_group("input")
    g.add_argument("--exposures", default="auto",
                   help="auto (EXIF times when every image has one, else one exposure) | times.txt "
                        "(one time per image) | "
                   "EVs, one per image in order, like 0,-2,2 | exif | learn | none (default: auto)")
    g.add_argument("--resize", help="scale factor (0.5) or size WxH")
    g.add_argument("--reference",
                   help="the view to fuse into: middle, first, last or an image index (default: "
                        "middle; export.reference)")
    common_model_args(f)
    return f


def pick_exposures(spec: str, clip):
    """``auto``: EXIF times when every image has one, else a single exposure; anything else as
    :func:`layercam.io.parse_exposures`, a list of EVs giving one per image (a stack has no cycle)."""
    from layercam.io import parse_exposures

    if (spec or "").strip().lower() == "auto":
        ex = clip.exif_exposures
        if ex is not None and all(v is not None and v > 0 for v in ex):
            return parse_exposures("exif", clip)
        e = parse_exposures("none", clip)
        e.reason = "auto: no EXIF exposure times, one exposure assumed (pass --exposures times.txt or learn otherwise)"
        return e
    return parse_exposures(spec, clip, each=True)


def run(args) -> int:
    from layercam.core.errors import LayercamError
    from layercam.cli import before_stages, open_clip
    from layercam.core.geometry import reference_index
    from layercam.pipelines.tasks import run_task

    if args.reference is not None:
        args.overrides = [f"export.reference={args.reference}", *args.overrides]
    cfg = load_cfg(args)
    out = Path(args.out) if args.out else default_out(args.inputs)
    with before_stages(out):
        clip = open_clip(args, cfg, out, "fuse-stack", args.resize)
        if clip.T < 2:
            raise LayercamError(f"fuse-stack needs at least 2 images, got {clip.T}")
        reference_index(cfg.export.reference, clip.T)  # a bad --reference fails now, not after training
        exposures = pick_exposures(args.exposures, clip)
    ctx = run_task("fuse-stack", clip, exposures, cfg, out, progress=not args.quiet)
    finish(ctx)
    if not args.quiet:
        ex = ctx.results["export"].summary
        print(f"fused into the view of image {ex['reference']} ({ex['reference_name']}): "
              f"{out / 'fused.exr'}, {out / 'fused.png'}")
    return 0
