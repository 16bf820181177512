"""``layercam deblur-video``: a blurry, shaky video -> sharp frames in the input's tonality."""

from __future__ import annotations

import argparse
from pathlib import Path

from layercam.core.presets import settings_help
from layercam.cli import (EPILOG, before_stages, common_model_args, default_out, finish, input_args,
                          load_cfg, open_clip, window_args)


def register(sub) -> argparse.ArgumentParser:
    d = sub.add_parser(
        "deblur-video",
        help="blurry, shaky video -> sharp frames (PNG + mp4), HDR EXR too when exposures vary",
        description=(
            "Fits the scene with the blur generator explaining each frame's blur, then renders every frame "
            "through the learned tone mapper at the frame's own exposure with the blur generator dropped, "
            "kept pixel by pixel where the model re-blurred reproduces the input within the input's noise, "
            "the input elsewhere: frames/frame_00000.png, trust/frame_00000.png (white: the sharp render kept), "
            "deblurred.mp4, hdr/frame_00000.exr (the render, only when exposures vary), "
            "crf.json/png, psf.json (learned blur per frame), report.json, checkpoint.pt. The video keeps the input's "
            "frame rate and sound."
        ),
        epilog=EPILOG + "\n\n" + settings_help(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    input_args(d, "none")
    common_model_args(d)
    window_args(d)
    return d


def run(args) -> int:
    from layercam.core.errors import LayercamError
    from layercam.io import parse_exposures
    from layercam.io.masks import load_masks
    from layercam.pipelines.tasks import run_task

    cfg = load_cfg(args)
    out = Path(args.out) if args.out else default_out(args.inputs)
    with before_stages(out):
        clip = open_clip(args, cfg, out, "deblur-video", args.resize, args.max_frames, args.stride)
        if clip.T < 2:
            raise LayercamError("deblur-video needs at least 2 frames (the blur of one frame is "
                                "explained by the others)")
        exposures = parse_exposures(args.exposures, clip, args.ev_step, args.force_ev_step)
        masks = load_masks(args.masks, clip) if args.masks else None
    ctx = run_task("deblur-video", clip, exposures, cfg, out, masks=masks, progress=not args.quiet,
                   window=args.window, ray=args.ray)
    finish(ctx)
    return 0
