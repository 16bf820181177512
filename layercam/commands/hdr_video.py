"""``layercam hdr-video``: alternating-exposure video -> linear HDR EXR frames + preview."""

from __future__ import annotations

import argparse
from pathlib import Path

from layercam import distributed
from layercam.cli import EPILOG, before_stages, common_model_args, default_out, finish, input_args, load_cfg, open_clip


def register(sub) -> argparse.ArgumentParser:
    h = sub.add_parser("hdr-video", help="alternating-exposure video -> linear HDR EXR frames + preview", description="Alternating-exposure (or any varying-exposure) video to linear HDR: hdr/frame_00000.exr, preview.mp4, crf.json/png, report.json, checkpoint.pt.", epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    input_args(h, "alt")
    common_model_args(h)
    distributed.add_args(h)
    return h


def run(args) -> int:
    from layercam.io import parse_exposures
    from layercam.io.masks import load_masks
    from layercam.pipelines.stages import device_of
    from layercam.pipelines.tasks import run_task

    cfg = load_cfg(args)
    device = device_of(cfg.train.device)  # a missing GPU is said before any work
    if distributed.launch_requested(args):
        return distributed.launch(args, device)
    with distributed.session(device):  # joins the process group under torchrun, else nothing
        out = Path(args.out) if args.out else default_out(args.inputs)
        with before_stages(out):
            clip = open_clip(args, cfg, out, "hdr-video", args.resize, args.max_frames, args.stride)
            exposures = parse_exposures(args.exposures, clip, args.ev_step, args.force_ev_step)
            masks = load_masks(args.masks, clip) if args.masks else None
        ctx = run_task("hdr-video", clip, exposures, cfg, out, masks=masks, progress=not args.quiet and distributed.is_main())
        finish(ctx)
    return 0
