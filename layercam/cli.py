"""``layercam`` command line. Heavy imports (torch, cv2) happen inside the commands, so that
``layercam --help`` answers at once."""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
from pathlib import Path

from layercam.core.config import DEFAULT_PRESET
from layercam.core.errors import LayercamError

EPILOG = """examples:
  layercam demo                                   # built-in synthetic clip, with metrics
  layercam hdr-video in.mp4 --exposures alt --ev-step 3 --out runs/clip
  layercam hdr-video frames/ --exposures times.txt --preset fast
  layercam hdr-video in.mp4 --set train.steps=500 --set scene.grid_levels=8

Re-running a command with the same input and settings skips finished stages; after Ctrl-C (or a
crash) the same command again goes on: training resumes from its last checkpoint, an unfinished
export is redone. One command at a time per run folder (RUN/layercam.lock)."""


class Parser(argparse.ArgumentParser):
    """argparse with the project's one-line errors: ``error: ...`` and exit code 2 (usage: --help)."""

    def error(self, message: str):
        self.exit(2, f"error: {message} (see {self.prog} --help)\n")


def number(kind: type = float, low: float | None = None, strict: bool = False, high: float | None = None):
    """An argparse ``type`` reading a finite ``kind`` (int or float) within ``[low, high]`` (``low``
    excluded when ``strict``): a bad number is refused before any work, in one line."""

    def read(text: str):
        try:
            v = kind(text) if kind is float else int(text)
        except ValueError:
            raise argparse.ArgumentTypeError("expected "
                                             f"{'an integer' if kind is int else 'a number'}, got "
                                             f"{text!r}") from None
        if not math.isfinite(v):
            raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
        if low is not None and (v <= low if strict else v < low):
            raise argparse.ArgumentTypeError(f"must be {'>' if strict else '>='} {low:g}, got {text}")
        if high is not None and v > high:
            raise argparse.ArgumentTypeError(f"must be at most {high:g}, got {text}")
        return v

    read.__name__ = kind.__name__  # argparse names the type in its messages
    return read


POSITIVE_INT = number(int, 1)
FPS = number(float, 0, strict=True, high=1000)


def common_model_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("settings")
    g.add_argument("--preset", default=DEFAULT_PRESET,
                   help="speed/quality preset: fast, balanced, quality, paper, or a .toml file "
                        f"(default: {DEFAULT_PRESET})")
    g.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override one setting, e.g. train.steps=500 (repeatable)")
    g.add_argument("--steps", type=POSITIVE_INT, help="shortcut for --set train.steps=N")
    g.add_argument("--device", choices=["cpu", "cuda", "auto"],
                   help="where to train and render: auto (default: CUDA when torch sees a GPU, "
                        "else the CPU), cpu or cuda")
    m = p.add_argument_group("model (default: chosen by analysis of the clip)")
    m.add_argument("--layers", type=int, choices=[1, 2],
                   help="scene layers: 1, or 2 for an object that moves on its own (alpha and "
                        "atlases per layer, editable with layercam edit); the analysis chooses "
                        "when not given")
    m.add_argument("--tone-mapper", choices=["learned", "fixed"], help="learn the camera response, or assume sRGB")
    m.add_argument("--blur", choices=["off", "3x3", "5x5"], help="blur generator patch size, or off")
    m.add_argument("--max-offset", type=number(float, 0), help="blur generator's maximum offset in pixels")
    m.add_argument("--flow-loss", choices=["on", "off"], help="optical-flow consistency loss")
    p.add_argument("--quiet", action="store_true", help="no progress bars or messages")


def input_args(p: argparse.ArgumentParser, exposures_default: str | None) -> None:
    p.add_argument("inputs", nargs="+", help="a video (mp4, mov, avi, mkv), a folder of frames, or image files")
    p.add_argument("--out", help="run folder (default: runs/<input name>)")
    g = p.add_argument_group("input")
    g.add_argument("--exposures", default=exposures_default,
                   help="alt | alt3 | an EV cycle like 0,3 | times.txt (one time per frame) | exif "
                        "| learn | none")
    g.add_argument("--ev-step", type=number(float, 0, strict=True),
                   help="EV between alternating exposures (alt/alt3); learned when omitted. "
                        "Checked against the EV the frames measure: more than 2 EV apart is said, "
                        "more than 2 EV and a factor of 2 apart is refused")
    g.add_argument("--force-ev-step", action="store_true",
                   help="use --ev-step even where the frames measure a very different ratio")
    g.add_argument("--max-frames", type=POSITIVE_INT, help="use at most N frames")
    g.add_argument("--stride", type=POSITIVE_INT, default=1, help="use every K-th frame")
    g.add_argument("--resize", help="scale factor (0.5) or size WxH")
    g.add_argument("--masks",
                   help="folder of foreground masks, one PNG per frame (two-layer scenes); without "
                        "it the foreground "
                   "is found from its motion, helped by a local Mask R-CNN weights file if you pass one "
                   "(--set segment.detector=PATH; nothing is downloaded)")


def _window(text: str) -> int:
    if text.strip().lower() in ("off", "0"):
        return 0
    return number(int, 3)(text)


_window.__name__ = "window"


def window_args(p: argparse.ArgumentParser) -> None:
    """``--window`` and ``--ray``: a long clip as windows of frames (``layercam.pipelines.windows``)."""
    g = p.add_argument_group("long clips")
    g.add_argument("--window", type=_window, metavar="N|off", help=(
        "train the clip as overlapping windows of N frames, each its own model sharing one camera (the response "
        "curve and exposures learned on the first window), joined by a cross-fade over their "
        "overlap weighted, pixel by pixel, by how well each window "
        "reproduces the overlap's frames; off: one "
        "model. Default: windows where the camera's motion spans more than the atlas holds at one cell per pixel "
        "(the analysis says so); each window resumes on its own"))
    g.add_argument("--ray", metavar="auto|ADDRESS", help=(
        "train the windows as tasks on a Ray cluster (one GPU each when it has GPUs, else one CPU; the first window "
        "first, then the others in parallel): auto = the cluster this machine belongs to, else one started here; "
        "or HOST:PORT / ray://HOST:PORT. The run folder must be reachable at the same path from every node. "
        "Needs pip install 'layercam[ray]'"))


def nproc_args(p: argparse.ArgumentParser) -> None:
    """``--nproc`` for a command that supports data-parallel training (:func:`layercam.engine.distributed.launch`)."""
    p.add_argument(
        "--nproc", type=number(int, 1), default=1, metavar="N",
        help="train with N data-parallel processes on this machine (torch.distributed: gloo on CPU, nccl "
        "with --device cuda, one GPU each); or start the command under torchrun (multi-node) instead. "
        "Default 1: one process, which on a few CPU cores is as fast",
    )


COMMAND_MODULES = ["hdr_video", "demo", "bench", "deblur_video", "fuse_stack", "render", "batch",
                   "edit"]  # each layercam/commands/<name>.py has register(sub) and run(args)


def build_parser() -> argparse.ArgumentParser:
    import importlib

    p = Parser(prog="layercam",
               description="Recover what the camera lost: sharp, all-in-focus, linear HDR frames "
                           "from videos and photo stacks, by learning a layered scene and an "
                           "implicit camera model per clip.", epilog=EPILOG,
               formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version="layercam 0.1.0")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        mod = importlib.import_module(f"layercam.commands.{name}")
        sp = mod.register(sub)
        sp.set_defaults(_run=mod.run)
    return p


def load_cfg(args):
    """The preset, then the model flags (``--layers`` ... as ``model.*``/``blur.*`` settings), the
    shortcuts and each ``--set``: checked, one line and exit 2 on a bad value."""
    from layercam.core.presets import load_config, model_overrides

    overrides = model_overrides(args.layers, args.tone_mapper, args.blur, args.max_offset, args.flow_loss)
    if args.steps is not None:
        overrides.append(f"train.steps={args.steps}")
    if args.device:
        overrides.append(f"train.device={args.device}")
    return load_config(args.preset, overrides + list(args.overrides))


def open_clip(args, cfg, out: Path, task: str, resize=None, max_frames=None, stride: int = 1):
    """The command's clip, decoded into the run folder's cache (``RUN/cache/frames-<key>/``, reused
    when the same input is run again), once what can be checked without decoding it has been: the
    run folder's ``outputs.json`` and foreign files (:mod:`layercam.pipelines.publish`), ``--ray``'s
    package and what the run will cost (:mod:`layercam.engine.estimate`, from the input's header). One line
    and nothing written when any of them refuses."""
    from layercam.engine.estimate import check, disk_used, estimate
    from layercam.io import load_clip, probe_clip
    from layercam.pipelines import publish
    from layercam.pipelines.export import outputs_for

    if out.exists() and not out.is_dir():
        raise LayercamError(f"output folder {out} is a file, not a folder")
    if getattr(args, "ray", None):
        from layercam.engine import cluster

        cluster.available()
    publish.check_folder(out, outputs_for(task))
    inputs = args.inputs if len(args.inputs) > 1 else args.inputs[0]
    info = probe_clip(inputs, max_frames=max_frames, stride=stride, resize=resize)
    check(estimate(info, cfg, task), out, disk_used(out / "cache"))
    return load_clip(inputs, max_frames=max_frames, stride=stride, resize=resize, cache=out / "cache")


@contextlib.contextmanager
def before_stages(out: Path):
    """What a command does before its stages run (load the clip, read its exposures and masks):
    when it fails, what it wrote is removed again: the frames it decoded into the cache, and the
    run folder itself when it made it and nothing else is in it."""
    import shutil

    existed = out.exists()
    try:
        yield
    except BaseException:
        cache = out / "cache"
        if cache.is_dir():
            for p in cache.iterdir():
                if p.name.startswith("frames-") and (p / ".made").exists():
                    shutil.rmtree(p, ignore_errors=True)
        if not existed:
            for p in (cache, out):
                with contextlib.suppress(OSError):
                    p.rmdir()
        raise
    else:
        cache = out / "cache"
        if cache.is_dir():
            for p in cache.glob("frames-*/.made"):
                p.unlink(missing_ok=True)


def default_out(inputs: list[str]) -> Path:
    first = Path(inputs[0])
    return Path("runs") / (first.stem if first.suffix else first.name or "run")


def finish(ctx) -> None:
    """One closing line: where the outputs are and how training ended."""
    if ctx.progress:
        tr = ctx.results["train"]
        if tr.windows is not None:  # a long clip's windows (layercam.pipelines.windows)
            losses = ", ".join(f"{(w.get('final_loss') or {}).get('total', float('nan')):.4g}" for w in tr.windows)
            print(f"done: {ctx.run_dir}  ({len(tr.windows)} windows, train {tr.steps} steps in "
                  f"all, final losses {losses})")
            return
        fl = tr.final_loss or {}
        print(f"done: {ctx.run_dir}  (train {tr.steps} steps, final loss {fl.get('total', float('nan')):.4g})")


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:  # --help, --version, or a bad option (one line already printed)
        return e.code if isinstance(e.code, int) else 2
    args._argv = list(sys.argv[1:] if argv is None else argv)  # for commands that re-launch themselves (--nproc)
    if not args.command:
        parser.print_help()
        return 0
    try:
        with _term_as_interrupt():
            return args._run(args)
    except LayercamError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("\ninterrupted: run the same command again to go on (training resumes from its last "
              "checkpoint, unfinished outputs are redone)", file=sys.stderr)
        return 130


@contextlib.contextmanager
def _term_as_interrupt():
    """SIGTERM (``kill PID``, a scheduler's stop) stops a command as Ctrl-C does."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum, frame):
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
