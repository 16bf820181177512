"""``layercam render``: re-render a finished run with new camera settings.

* ``--exposure EV``: every frame through the learned tone mapper at ``EV`` stops from the run's
  reference exposure (the median of its frames' exposures), the blur generator dropped (sharp)
  unless ``--keep-blur``.
* ``--focus F``: one view through the blur generator at the fractional image index ``F`` (its
  per-image embedding interpolated between the training images ``floor(F)`` and ``ceil(F)``), at
  the exposure interpolated the same way (or at ``--exposure EV``).
* ``--sweep exposure|focus``: a video (and its frames) of one view sweeping over ``--range``.

Outputs go to ``RUN/render/`` (or ``--out``), each with a ``.json`` sidecar saying what it is.
"""

from __future__ import annotations

import argparse
import contextlib
import math
from pathlib import Path

from layercam.cli import FPS, number
from layercam.errors import LayercamError

EXAMPLES = """examples:
  layercam render runs/clip --exposure +2            # every frame two stops brighter, sharp
  layercam render runs/stack --focus 0.5             # focus half-way between images 0 and 1
  layercam render runs/stack --sweep focus --steps 30
  layercam render runs/clip --sweep exposure --range -4,4 --frame 10"""


def register(sub) -> argparse.ArgumentParser:
    r = sub.add_parser(
        "render",
        help="re-render a finished run at a new exposure or focus, or as a sweep video",
        description="Re-renders a finished run (its checkpoint.pt) keeping parts of the learned camera: the tone mapper at a new exposure, the blur generator at an interpolated focus.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    r.add_argument("run", help="a finished layercam run folder (holds checkpoint.pt)")
    r.add_argument("--exposure", type=number(float, -24, high=24), metavar="EV", help="stops relative to the run's reference exposure (median of its frames')")
    r.add_argument("--focus", type=number(float, 0), metavar="F", help="fractional training-image index whose blur to render, e.g. 0.5")
    r.add_argument("--sweep", choices=["exposure", "focus"], help="a video sweeping over exposure or focus")
    r.add_argument("--range", dest="sweep_range", metavar="A,B", help="sweep range (default: -4,4 EV; focus: first,last image)")
    r.add_argument("--steps", type=number(int, 2, high=1000), default=25, help="sweep steps (default 25)")
    r.add_argument("--frame", type=number(int, 0), help="the view for --focus and sweeps (default: the run's reference image, else the middle frame)")
    r.add_argument("--keep-blur", action="store_true", help="exposure renders: keep each frame's learned blur")
    r.add_argument("--fps", type=FPS, help="video frame rate (default: the input's for --exposure, 12 for sweeps)")
    r.add_argument("--out", help="output folder (default: RUN/render)")
    r.add_argument("--overwrite", action="store_true", help="replace earlier renders of the same name")
    r.add_argument("--device", choices=["cpu", "cuda", "auto"], default="auto", help="auto (default: CUDA when present, else the CPU), cpu or cuda")
    r.add_argument("--quiet", action="store_true")
    return r


# -- rendering functions (used by the command and the tests) ----------------------------------------
def exposure_at(model, f: float) -> float:
    """log2 exposure at a fractional frame index (linear between neighbouring frames)."""
    import numpy as np

    v = model.exposure.values().detach().cpu().numpy().astype(np.float64)
    return float(np.interp(f, np.arange(len(v)), v))


def exposure_frames(model, meta: dict, ev: float, keep_blur: bool = False, chunk: int = 65536):
    """Every frame at ``ev`` stops from the reference exposure: ``(T, H, W, 3)``."""
    import numpy as np

    from layercam.render import render_frame

    hw = tuple(meta["frame_hw"])
    z = model.exposure.reference() + ev
    return np.stack([render_frame(model, t, hw, "ldr", log2_dt=z, blur=keep_blur, chunk=chunk)["ldr"] for t in range(int(meta["n_frames"]))])


def exposure_sweep(model, meta: dict, evs, frame: int, keep_blur: bool = False):
    """One view at each of ``evs`` (stops from the reference exposure): ``(N, H, W, 3)``."""
    import numpy as np

    from layercam.render import render_frame

    hw = tuple(meta["frame_hw"])
    z0 = model.exposure.reference()
    return np.stack([render_frame(model, frame, hw, "ldr", log2_dt=z0 + float(e), blur=keep_blur)["ldr"] for e in evs])


def focus_sweep(model, meta: dict, fs, frame: int, ev: float | None = None):
    """One view with the blur of each fractional image index in ``fs``: ``(N, H, W, 3)``; at the
    exposure interpolated at each ``f``, or at ``ev`` stops from the reference when given."""
    import numpy as np

    from layercam.render import render_frame

    hw = tuple(meta["frame_hw"])
    out = []
    for f in fs:
        z = exposure_at(model, float(f)) if ev is None else model.exposure.reference() + ev
        out.append(render_frame(model, frame, hw, "ldr", log2_dt=z, t_blur=float(f), blur=True)["ldr"])
    return np.stack(out)


# -- command -------------------------------------------------------------------------------------
def _range(text: str | None, default: tuple[float, float]) -> tuple[float, float]:
    if text is None:
        return default
    try:
        a, b = (float(v) for v in text.replace(":", ",").split(","))
    except ValueError:
        raise LayercamError(f"--range expects two numbers A,B, got {text!r}") from None
    if not (math.isfinite(a) and math.isfinite(b)):
        raise LayercamError(f"--range must be finite, got {text!r}")
    return a, b


def _check_ev(ev: float | None) -> None:
    if ev is not None and not (math.isfinite(ev) and abs(ev) <= 24):
        raise LayercamError(f"--exposure must be within +-24 stops, got {ev}")


def _products(args, out: Path) -> dict:
    """What this command writes into ``out``: per product, its names there, the last one (a sidecar
    ``.json``) marking it finished. A finished product is kept unless ``--overwrite``; an unfinished
    one (an interrupted render) is redone."""
    p = {}
    if args.sweep:
        p["sweep"] = [f"sweep_{args.sweep}", f"sweep_{args.sweep}.mp4", f"sweep_{args.sweep}.json"]
    if args.focus is not None:
        name = f"focus_{args.focus:.2f}" + ("" if args.exposure is None else f"_ev{args.exposure:+.2f}")
        p["focus"] = [f"{name}.png", f"{name}.json"]
    elif args.exposure is not None and args.sweep is None:
        p["exposure"] = [f"exposure_{args.exposure:+.2f}"]  # one folder, renamed into place when complete
    for names in p.values():
        marker = out / names[-1] / "render.json" if len(names) == 1 else out / names[-1]
        if marker.exists() and not args.overwrite:
            raise LayercamError(f"{out / names[0]} exists already; pass --overwrite or choose another --out")
    return p


def run(args) -> int:
    from layercam.io.lock import run_lock

    if args.exposure is None and args.focus is None and args.sweep is None:
        raise LayercamError("nothing to render: give --exposure EV, --focus F or --sweep exposure|focus")
    from layercam.io.atomic import partials_removed_on_error

    with run_lock(args.run) if Path(args.run, "checkpoint.pt").is_file() else contextlib.nullcontext():  # one writer per run folder
        with partials_removed_on_error(_out_dir(args)):
            return _render(args)


def _out_dir(args) -> Path:
    return Path(args.out) if args.out else Path(args.run) / "render"


def _render(args) -> int:
    import numpy as np

    from layercam.checkpoint import load_run_model
    from layercam.geometry import middle_frame
    from layercam.io import write_png, write_video
    from layercam.io.atomic import commit_staged, ensure_writable_dir, staging_dir
    from layercam.pipelines.runner import write_json
    from layercam.pipelines.stages import device_of

    model, meta = load_run_model(Path(args.run), device_of(args.device))
    T = int(meta["n_frames"])
    has_blur = model.blur is not None
    if (args.focus is not None or args.sweep == "focus") and not has_blur:
        raise LayercamError(f"{args.run}: this run has no blur generator (blur was off), so there is no focus to change")
    if args.focus is not None and not (0 <= args.focus <= T - 1):
        raise LayercamError(f"--focus must lie between 0 and {T - 1} (the training images' indices), got {args.focus}")
    if args.frame is not None and not 0 <= args.frame < T:
        raise LayercamError(f"--frame must be between 0 and {T - 1}, got {args.frame}")
    sweep_range = None
    if args.sweep == "exposure":
        sweep_range = _range(args.sweep_range, (-4.0, 4.0))
        _check_ev(sweep_range[0]), _check_ev(sweep_range[1])
    elif args.sweep == "focus":
        sweep_range = _range(args.sweep_range, (0.0, float(T - 1)))
        if not (0 <= min(sweep_range) and max(sweep_range) <= T - 1):
            raise LayercamError(f"focus --range must lie within 0..{T - 1}, got {args.sweep_range}")
    default_view = int(meta.get("reference", middle_frame(T)))
    out = ensure_writable_dir(_out_dir(args))
    products = _products(args, out)
    z0 = model.exposure.reference()
    say = (lambda m: None) if args.quiet else print
    base = {"run": str(args.run), "reference_log2_exposure": z0, "frame_log2_exposures": model.exposure.values().detach().cpu().tolist()}

    if args.sweep:
        a, b = sweep_range
        view = default_view if args.frame is None else args.frame
        stage = staging_dir(out, products["sweep"][-1])
        if args.sweep == "exposure":
            evs = np.linspace(a, b, args.steps)
            _write_sweep(stage, "exposure", exposure_sweep(model, meta, evs, view, args.keep_blur), args.fps, {**base, "what": "exposure sweep", "view": view, "ev": evs.tolist(), "blur": args.keep_blur})
        else:
            fs = np.linspace(a, b, args.steps)
            _write_sweep(stage, "focus", focus_sweep(model, meta, fs, view, args.exposure), args.fps, {**base, "what": "focus sweep", "view": view, "focus": fs.tolist(), "exposure_ev": args.exposure})
        commit_staged(stage, out, products["sweep"])
        say(f"{args.sweep} sweep {a:+g}..{b:+g} of view {view}: {out / products['sweep'][1]}")
    if "focus" in products:
        png, side = products["focus"]
        view = args.frame if args.frame is not None else (int(meta["reference"]) if "reference" in meta else int(round(args.focus)))
        stage = staging_dir(out, side)
        write_png(stage / png, focus_sweep(model, meta, [args.focus], view, args.exposure)[0])
        write_json(stage / side, {**base, "what": "focus", "focus": args.focus, "view": view, "exposure_ev": args.exposure})
        commit_staged(stage, out, products["focus"])
        say(f"focus {args.focus:g} of view {view}: {out / png}")
    if "exposure" in products:
        (name,) = products["exposure"]
        stage = staging_dir(out, name)
        frames = exposure_frames(model, meta, args.exposure, args.keep_blur)
        _write_steps(stage / name, frames, write_png, prefix="frame_", width=5)
        if T > 1:
            write_video(stage / name / "video.mp4", frames, fps=args.fps or float(meta.get("fps", 24.0)))
        write_json(stage / name / "render.json", {**base, "what": "exposure", "ev": args.exposure, "log2_exposure": z0 + args.exposure, "blur": args.keep_blur})
        commit_staged(stage, out, products["exposure"])
        say(f"{T} frames at {args.exposure:+g} EV: {out / name}")
    return 0


def _write_sweep(out: Path, kind: str, imgs, fps: float | None, info: dict) -> None:
    """``sweep_{kind}.mp4``, its steps as PNGs in ``sweep_{kind}/`` and ``sweep_{kind}.json``."""
    from layercam.io import write_png, write_video
    from layercam.pipelines.runner import write_json

    _write_steps(out / f"sweep_{kind}", imgs, write_png)
    write_video(out / f"sweep_{kind}.mp4", imgs, fps=fps or 12.0)
    write_json(out / f"sweep_{kind}.json", info)


def _write_steps(folder: Path, imgs, write_png, prefix: str = "step_", width: int = 3) -> None:
    from layercam.interrupts import reached

    folder.mkdir(parents=True, exist_ok=True)
    for i, img in enumerate(imgs):
        reached("render", i)
        write_png(folder / f"{prefix}{i:0{width}d}.png", img)
