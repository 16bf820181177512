"""``layercam hdr-video``: alternating-exposure video -> linear HDR EXR frames + preview."""

from __future__ import annotations

import argparse
from pathlib import Path

from layercam.core.presets import settings_help
from layercam.engine import distributed
from layercam.cli import (EPILOG, before_stages, common_model_args, default_out, finish, input_args,
                          load_cfg, nproc_args, number, open_clip, window_args)


def register(sub) -> argparse.ArgumentParser:
    h = sub.add_parser("hdr-video",
                       help="alternating-exposure video -> linear HDR EXR frames, an HDR video + "
                            "preview",
                       description="Alternating-exposure (or any varying-exposure) video to linear "
                                   "HDR: hdr/frame_00000.exr, hdr.mp4 (HDR10 or HLG, to watch on "
                                   "an HDR screen), preview.mp4 (SDR), crf.json/png, report.json, "
                                   "checkpoint.pt. The videos keep the input's frame rate and "
                                   "sound.", epilog=EPILOG + "\n\n" + settings_help(),
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    input_args(h, "alt")
    hdr_video_args(h)
    common_model_args(h)
    window_args(h)
    nproc_args(h)
    return h


def hdr_video_args(p: argparse.ArgumentParser, render: bool = False) -> None:
    """``--hdr-format`` and ``--nits-white`` (hdr-video; render, where ``--hdr-format`` asks for one)."""
    g = p.add_argument_group("HDR video (HEVC Main 10, BT.2020)" if render
                             else "HDR video (hdr.mp4: HEVC Main 10, BT.2020)")
    g.add_argument("--hdr-format", choices=["pq", "hlg"] if render else ["pq", "hlg", "none"], help=(
        "pq: HDR10 (SMPTE ST 2084, mastering display and MaxCLL/MaxFALL from the frames: HDR TVs, "
        "phones, laptops, YouTube); "
        "hlg: Hybrid Log-Gamma (ARIB STD-B67: also looks right on SDR screens)" + (
            "; writes the run's hdr/ frames as hdr_FORMAT.mp4 (--exposure EV makes them EV stops "
            "brighter)" if render else "; none: no hdr.mp4 (default: pq)")))
    g.add_argument("--nits-white", type=number(float, 0, strict=True, high=1000), metavar="N", help=(
        "brightness of diffuse white in cd/m2 (default 203, ITU-R BT.2408's reference white); "
        "diffuse white is what an SDR camera at the "
        "clip's median exposure records as full signal; light above the 1000 cd/m2 display peak is "
        "rolled off smoothly"))


def hdr_overrides(args) -> list[str]:
    """``--hdr-format`` / ``--nits-white`` as ``--set export.*`` items (before the user's own ``--set``)."""
    out = [f"export.hdr_format={args.hdr_format}"] if args.hdr_format else []
    return out + ([f"export.nits_white={args.nits_white}"] if args.nits_white is not None else [])


def run(args) -> int:
    from layercam.io import parse_exposures
    from layercam.io.masks import load_masks
    from layercam.engine.resolve import device_of
    from layercam.pipelines.tasks import run_task

    args.overrides = hdr_overrides(args) + list(args.overrides)
    cfg = load_cfg(args)
    device = device_of(cfg.train.device)  # a missing GPU is said before any work
    if args.ray and (args.nproc > 1 or distributed.env_world_size() > 1):
        from layercam.core.errors import LayercamError

        raise LayercamError("--ray trains a long clip's windows as tasks; leave --nproc (and torchrun) out")
    if distributed.launch_requested(args):
        return distributed.launch(args, device)
    with distributed.session(device):  # joins the process group under torchrun, else nothing
        out = Path(args.out) if args.out else default_out(args.inputs)
        with before_stages(out):
            clip = open_clip(args, cfg, out, "hdr-video", args.resize, args.max_frames, args.stride)
            exposures = parse_exposures(args.exposures, clip, args.ev_step, args.force_ev_step)
            masks = load_masks(args.masks, clip) if args.masks else None
        ctx = run_task("hdr-video", clip, exposures, cfg, out, masks=masks,
                       progress=not args.quiet and distributed.is_main(), window=args.window,
                       ray=args.ray)
        finish(ctx)
    return 0
