"""``layercam render``: re-render a finished run with new camera settings.

* ``--exposure EV``: every frame through the learned tone mapper at ``EV`` stops from the run's
  reference exposure (the median of its frames' exposures), the blur generator dropped (sharp)
  unless ``--keep-blur``.
* ``--focus F``: one view through the blur generator at the fractional image index ``F`` (its
  per-image embedding interpolated between the training images ``floor(F)`` and ``ceil(F)``), at
  the exposure interpolated the same way (or at ``--exposure EV``).
* ``--sweep exposure|focus``: a video (and its frames) of one view sweeping over ``--range``.
* ``--hdr-format pq|hlg``: the run's linear HDR frames (``RUN/hdr/``) as an HDR video
  (:mod:`layercam.io.hdr_video`), ``--exposure EV`` stops brighter when given.

Outputs go to ``RUN/render/`` (or ``--out``), each with a ``.json`` sidecar saying what it is. The
videos have the input's frame rate (unless ``--fps``), and those of the clip's frames carry its sound.

A long clip's run (``windows.json``: windows of frames, each its own model sharing one camera):
frame indices, ``--focus`` and ``--frame`` are the clip's; exposures count from the clip's reference
(the median of every frame's exposure); ``--exposure`` renders each window's frames and joins them
across the overlaps as the export did; a view (``--focus``, a sweep) comes from the window that
holds its frame most, whose blur generator knows that window's images only.
"""

from __future__ import annotations

import argparse
import contextlib
import math
from pathlib import Path

from layercam.cli import FPS, number
from layercam.core.errors import LayercamError

EXAMPLES = """examples:
  layercam render runs/clip --exposure +2            # every frame two stops brighter, sharp
  layercam render runs/stack --focus 0.5             # focus half-way between images 0 and 1
  layercam render runs/stack --sweep focus --steps 30
  layercam render runs/clip --sweep exposure --range -4,4 --frame 10
  layercam render runs/clip --hdr-format hlg           # the run's HDR frames as an HLG video
  layercam render runs/clip --hdr-format pq --nits-white 300 --exposure -1"""


def register(sub) -> argparse.ArgumentParser:
    r = sub.add_parser(
        "render",
        help="re-render a finished run at a new exposure or focus, or as a sweep video",
        description="Re-renders a finished run (its checkpoint.pt) keeping parts of the learned "
                    "camera: the tone mapper at a new exposure, the blur generator at an "
                    "interpolated focus.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    r.add_argument("run", help="a finished layercam run folder (holds checkpoint.pt)")
    r.add_argument("--exposure", type=number(float, -24, high=24), metavar="EV",
                   help="stops relative to the run's reference exposure (median of its frames')")
    r.add_argument("--focus", type=number(float, 0), metavar="F",
                   help="fractional training-image index whose blur to render, e.g. 0.5")
    r.add_argument("--sweep", choices=["exposure", "focus"], help="a video sweeping over exposure or focus")
    r.add_argument("--range", dest="sweep_range", metavar="A,B",
                   help="sweep range (default: -4,4 EV; focus: first,last image)")
    r.add_argument("--steps", type=number(int, 2, high=1000), default=25, help="sweep steps (default 25)")
    r.add_argument("--frame", type=number(int, 0),
                   help="the view for --focus and sweeps (default: the run's reference image, else "
                        "the middle frame; a long clip's windows: rendered by the window that "
                        "holds it)")
    r.add_argument("--keep-blur", action="store_true", help="exposure renders: keep each frame's learned blur")
    r.add_argument("--fps", type=FPS,
                   help="video frame rate (default: the input's; the input's sound is kept only at "
                        "its rate)")
    r.add_argument("--out", help="output folder (default: RUN/render)")
    r.add_argument("--overwrite", action="store_true", help="replace earlier renders of the same name")
    r.add_argument("--device", choices=["cpu", "cuda", "auto"], default="auto",
                   help="auto (default: CUDA when present, else the CPU), cpu or cuda")
    r.add_argument("--quiet", action="store_true")
    from layercam.commands.hdr_video import hdr_video_args

    hdr_video_args(r, render=True)
    return r


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


def run_audio(meta: dict, fps: float) -> dict | None:
    """The sound a video of the run's frames at ``fps`` carries over: the run's (its checkpoint's
    ``audio``, :func:`layercam.io.inputs.audio_plan`) when ``fps`` is the input's, else None."""
    a = meta.get("audio")
    return a if a and abs(float(fps) - float(meta.get("fps") or 24.0)) < 1e-6 else None


def _hdr_name(args) -> str:
    return f"hdr_{args.hdr_format}" + ("" if args.exposure is None else f"_ev{args.exposure:+.2f}")


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
    if args.hdr_format:
        p["hdr"] = [f"{_hdr_name(args)}.mp4", f"{_hdr_name(args)}.json"]
    elif args.exposure is not None and args.sweep is None and args.focus is None:
        p["exposure"] = [f"exposure_{args.exposure:+.2f}"]  # one folder, renamed into place when complete
    for names in p.values():
        marker = out / names[-1] / "render.json" if len(names) == 1 else out / names[-1]
        if marker.exists() and not args.overwrite:
            raise LayercamError(f"{out / names[0]} exists already; pass --overwrite or choose another --out")
    return p


def run(args) -> int:
    from layercam.io.lock import run_lock
    from layercam.pipelines.windows.index import INDEX

    if args.nits_white is not None and args.hdr_format is None:
        raise LayercamError("--nits-white sets the HDR video's diffuse white: give --hdr-format pq|hlg with it")
    if args.exposure is None and args.focus is None and args.sweep is None and args.hdr_format is None:
        raise LayercamError("nothing to render: give --exposure EV, --focus F, --sweep "
                            "exposure|focus or --hdr-format pq|hlg")
    from layercam.io.atomic import partials_removed_on_error

    finished = Path(args.run, "checkpoint.pt").is_file() or Path(args.run, INDEX).is_file()
    with run_lock(args.run) if finished else contextlib.nullcontext():  # one writer per run folder
        with partials_removed_on_error(_out_dir(args)):
            return _render(args)


def _out_dir(args) -> Path:
    return Path(args.out) if args.out else Path(args.run) / "render"


class _Views:
    """What a finished run renders from: one model, or a long clip's windows (``windows.json``:
    each window's model renders its frames, joined across their overlaps as the export joined them;
    one view, a focus or a sweep, comes from the window that holds its frame most). Frame indices
    and ``--focus`` are the clip's; exposures count from the clip's reference (the median of every
    frame's exposure)."""

    def __init__(self, run: Path, device: str):
        import numpy as np

        from layercam.engine.checkpoint import load_run_model
        from layercam.pipelines.windows import index as windows

        index = windows.read_index(run)
        if index is None:
            model, meta = load_run_model(run, device)
            self.models, self.metas, self.plan = [model], [meta], None
            self.T = int(meta["n_frames"])
            self.z0 = model.exposure.reference()
            self.shift = [0.0]
        else:
            loaded = [load_run_model(f, device) for f in windows.window_folders(run, index)]
            self.models, self.metas = [m for m, _ in loaded], [m for _, m in loaded]
            self.plan = windows.index_plan(index, run)
            self.T = int(index["frames"])
            gains = windows.index_gains(index)
            self.z0 = windows.clip_reference(self.models, gains)
            self.shift = [-float(np.log2(g)) for g in gains]  # window k at z renders as window 0 at
                                                              # z + shift: its irradiance is gain x
                                                              # window 0's
        self.has_blur = self.models[0].blur is not None
        self.reference = self.metas[0].get("reference") if self.plan is None else None

    def start(self, k: int) -> int:
        return 0 if self.plan is None else self.plan.windows[k][0]

    def window(self, frame: int) -> int:
        return 0 if self.plan is None else self.plan.holding(frame)

    def frame_exposures(self) -> list[float]:
        import numpy as np

        if self.plan is None:
            return self.models[0].exposure.values().detach().cpu().tolist()
        return [float(sum(w
                          * (float(self.models[k].exposure.values().detach().cpu().numpy()[t
            - self.start(k)]) - self.shift[k]) for k, w in self.plan.weights(t)))
                for t in np.arange(self.T)]

    def exposure_frames(self, ev: float, keep_blur: bool):
        """Every frame at ``ev`` stops from the clip's reference, ``(T, H, W, 3)``; a window's frames
        joined with its neighbour's by the export's cross-fade."""
        import numpy as np

        from layercam.scene.render import exposure_frames

        if self.plan is None:
            return exposure_frames(self.models[0], self.metas[0], ev, keep_blur, z0=self.z0)
        from layercam.pipelines.windows.plan import per_pixel

        per = [exposure_frames(m, meta, ev, keep_blur, z0=self.z0 + d) for m, meta,
               d in zip(self.models, self.metas, self.shift)]
        hw = per[0].shape[1:3]

        def joined(t: int):
            out = 0.0
            for k, w in self.plan.weights(t, hw):
                x = per[k][t - self.start(k)]
                out = out + per_pixel(w, x) * x
            return out
        return np.stack([joined(t) for t in range(self.T)]).astype(np.float32)


def _render(args) -> int:
    import numpy as np

    from layercam.core.geometry import middle_frame
    from layercam.io import write_png, write_video
    from layercam.io.atomic import commit_staged, ensure_writable_dir, staging_dir
    from layercam.pipelines.runner import write_json
    from layercam.engine.resolve import device_of
    from layercam.scene.render import exposure_sweep, focus_sweep

    v = _Views(Path(args.run), device_of(args.device))
    T = v.T
    if (args.focus is not None or args.sweep == "focus") and not v.has_blur:
        raise LayercamError(f"{args.run}: this run has no blur generator (blur was off), so there "
                            "is no focus to change")
    if args.focus is not None and not (0 <= args.focus <= T - 1):
        raise LayercamError(f"--focus must lie between 0 and {T - 1} (the training images' indices), got {args.focus}")
    if args.frame is not None and not 0 <= args.frame < T:
        raise LayercamError(f"--frame must be between 0 and {T - 1}, got {args.frame}")
    default_view = int(v.reference if v.reference is not None else middle_frame(T))
    sweep_range = None
    if args.sweep == "exposure":
        sweep_range = _range(args.sweep_range, (-4.0, 4.0))
        _check_ev(sweep_range[0]), _check_ev(sweep_range[1])
    elif args.sweep == "focus":
        view = default_view if args.frame is None else args.frame
        k = v.window(view)
        lo, hi = (0, T - 1) if v.plan is None else (v.plan.windows[k][0], v.plan.windows[k][1] - 1)
        sweep_range = _range(args.sweep_range, (float(lo), float(hi)))
        if not (lo <= min(sweep_range) and max(sweep_range) <= hi):
            where = ("" if v.plan is None
                     else f" (the images of window {k}, which holds view {view}: each window's "
                          "blur generator knows its own images)")
            raise LayercamError(f"focus --range must lie within {lo}..{hi}{where}, got {args.sweep_range}")
    out = ensure_writable_dir(_out_dir(args))
    products = _products(args, out)
    z0 = v.z0
    say = (lambda m: None) if args.quiet else print
    base = {"run": str(args.run), "reference_log2_exposure": z0, "frame_log2_exposures": v.frame_exposures()}
    meta0 = v.metas[0]
    fps = float(meta0.get("fps") or 24.0)  # the input's
    hdr_frames = None
    if "hdr" in products:  # checked before any work
        hdr_frames = sorted((Path(args.run) / "hdr").glob("frame_*.exr"))
        if len(hdr_frames) != T:
            raise LayercamError(f"{args.run}: --hdr-format needs the run's linear HDR frames, "
                                f"hdr/frame_*.exr ({T}); found {len(hdr_frames)} (hdr-video runs "
                                "have them)")
        from layercam.io.hdr_video import missing_for_hdr
        from layercam.io.ffmpeg import ffmpeg_exe

        missing = missing_for_hdr()
        if missing:
            raise LayercamError(f"cannot write an HDR video: ffmpeg ({ffmpeg_exe()}) has no "
                                f"{missing}; imageio-ffmpeg >= 0.8 ships an ffmpeg with it")

    def one(view: int):
        """The model of the window holding ``view``, its meta, the window's first frame and the
        reference exposure in its scale."""
        k = v.window(view)
        return v.models[k], v.metas[k], v.start(k), z0 + v.shift[k]

    if args.sweep:
        a, b = sweep_range
        view = default_view if args.frame is None else args.frame
        model, meta, a0, zk = one(view)
        stage = staging_dir(out, products["sweep"][-1])
        if args.sweep == "exposure":
            evs = np.linspace(a, b, args.steps)
            _write_sweep(stage, "exposure",
                         exposure_sweep(model, meta, evs, view - a0, args.keep_blur, z0=zk),
                         args.fps or fps,
                         {**base, "what": "exposure sweep", "view": view, "ev": evs.tolist(),
                          "blur": args.keep_blur})
        else:
            fs = np.linspace(a, b, args.steps)
            _write_sweep(stage, "focus",
                         focus_sweep(model, meta, fs - a0, view - a0, args.exposure, z0=zk),
                         args.fps or fps,
                         {**base, "what": "focus sweep", "view": view, "focus": fs.tolist(),
                          "exposure_ev": args.exposure})
        commit_staged(stage, out, products["sweep"])
        say(f"{args.sweep} sweep {a:+g}..{b:+g} of view {view}: {out / products['sweep'][1]}")
    if "focus" in products:
        png, side = products["focus"]
        view = args.frame if args.frame is not None else (int(v.reference)
                                                          if v.reference is not None
                                                          else int(round(args.focus)))
        model, meta, a0, zk = one(view)
        if v.plan is not None and not 0 <= args.focus - a0 <= len(meta["names"]) - 1:
            raise LayercamError(f"--focus {args.focus:g} and view {view} lie in different windows: "
                                "each window's blur generator knows its own images "
                                f"({a0}..{a0 + len(meta['names']) - 1} for view {view})")
        stage = staging_dir(out, side)
        write_png(stage / png, focus_sweep(model, meta, [args.focus - a0], view - a0, args.exposure, z0=zk)[0])
        write_json(stage / side,
                   {**base, "what": "focus", "focus": args.focus, "view": view,
                    "exposure_ev": args.exposure})
        commit_staged(stage, out, products["focus"])
        say(f"focus {args.focus:g} of view {view}: {out / png}")
    if "exposure" in products:
        (name,) = products["exposure"]
        stage = staging_dir(out, name)
        frames = v.exposure_frames(args.exposure, args.keep_blur)
        _write_steps(stage / name, frames, write_png, prefix="frame_", width=5)
        if T > 1:
            write_video(stage / name / "video.mp4", frames, fps=args.fps or fps,
                        audio=run_audio(meta0, args.fps or fps))
        write_json(stage / name / "render.json",
                   {**base, "what": "exposure", "ev": args.exposure,
                    "log2_exposure": z0 + args.exposure, "blur": args.keep_blur,
                                                  **({} if v.plan is None
                                                     else {"windows": v.plan.to_dict()["windows"],
                                                           "join": "each window's frames, "
                                                                   "cross-faded over the overlaps "
                                                                   "by their fits as in the export"})})
        commit_staged(stage, out, products["exposure"])
        say(f"{T} frames at {args.exposure:+g} EV: {out / name}")
    if "hdr" in products:
        from layercam.io import read_exr
        from layercam.io.hdr_video import ANCHOR, write_hdr_video
        from layercam.scene.render import white_radiance

        video, side = products["hdr"]
        stage = staging_dir(out, side)
        gain = 2.0 ** (args.exposure or 0.0)
        nits = args.nits_white or 203.0
        info = write_hdr_video(stage / video, lambda: (read_exr(p) * gain for p in hdr_frames),
                               args.fps or fps, args.hdr_format, white_radiance(v.models[0]), nits,
                               meta0.get("primaries", "bt709"),
                               audio=run_audio(meta0, args.fps or fps), progress=not args.quiet)
                               # fmt: skip
        write_json(stage / side,
                   {**base, "what": "HDR video of the run's hdr/ frames",
                    "exposure_ev": args.exposure, **info, "anchor": ANCHOR})
        commit_staged(stage, out, products["hdr"])
        if info["audio"] and not info["audio"]["kept"]:
            print(f"warning: {video} is written without the input's sound: {info['audio']['why']}", flush=True)
        say(f"{T} frames as {args.hdr_format.upper()} HDR video (diffuse white at {nits:g} cd/m2): {out / video}")
    return 0


def _write_sweep(out: Path, kind: str, imgs, fps: float, info: dict) -> None:
    """``sweep_{kind}.mp4``, its steps as PNGs in ``sweep_{kind}/`` and ``sweep_{kind}.json``."""
    from layercam.io import write_png, write_video
    from layercam.pipelines.runner import write_json

    _write_steps(out / f"sweep_{kind}", imgs, write_png)
    write_video(out / f"sweep_{kind}.mp4", imgs, fps=fps)  # one view, not the clip's time: no sound
    write_json(out / f"sweep_{kind}.json", info)


def _write_steps(folder: Path, imgs, write_png, prefix: str = "step_", width: int = 3) -> None:
    from layercam.core.interrupts import reached

    folder.mkdir(parents=True, exist_ok=True)
    for i, img in enumerate(imgs):
        reached("render", i)
        write_png(folder / f"{prefix}{i:0{width}d}.png", img)
