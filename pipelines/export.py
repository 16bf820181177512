"""The export stage: the run folder's outputs, written by the writers that the task's row of
:data:`TASK_WRITERS` names, followed by those every task writes (:data:`COMMON_WRITERS`).

====================  ======================================================================
writer                writes
====================  ======================================================================
``hdr``               ``hdr/frame_00000.exr`` (linear, camera dropped; with ``export.faithful``
                      corrected towards the frame where it saw well, :mod:`layercam.camera.faithful`),
                      ``preview.mp4`` (global Reinhard over the whole clip) and ``hdr.mp4``
                      (HDR10 or HLG from the EXRs, ``export.hdr_format``,
                      :mod:`layercam.io.hdr_video`)
``sharp``             ``frames/frame_00000.png`` and ``deblurred.mp4``: the tone mapper at each
                      frame's own exposure, blur generator dropped, kept per pixel where the model
                      re-blurred reproduces the input, the input elsewhere (``trust/``: the mask;
                      :mod:`.sharp`, :mod:`.view`); ``hdr/`` when exposures vary
``fused``             ``fused.exr`` (the scene for the reference view, camera dropped, faithful
                      to the reference image like ``hdr``) and
                      ``fused.png`` (tonemapped; with the fixed sRGB curve, the input's tonality)
``atlases``           ``atlases/`` and ``alpha/`` (:mod:`layercam.pipelines.atlas_export`)
``crf``               ``crf.json`` and ``crf.png``: the learned response per channel
``psf``               ``psf.json``: the learned blur per frame (a model with a blur generator)
``checkpoint``        ``checkpoint.pt``: what ``layercam render`` and ``edit`` read
====================  ======================================================================

Every video keeps the input's frame rate and carries its sound over
(:func:`layercam.pipelines.media.audio`). Every writer is ``writer(ctx, model, dest, cache) ->
dict`` (its part of the export summary): it
writes its outputs into ``dest`` and what the evaluate stage reads into ``cache``. Both are the
stage's cache folder: an interrupted export is redone there, and the finished outputs are published
to the top of the run folder with the report, as one set, when the run ends
(``pipelines/publish.py``; outputs of other settings are moved to ``previous/<their key>/``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from layercam.core.errors import LayercamError
from layercam.core.geometry import reference_index
from layercam.core.interrupts import reached
from layercam.pipelines.hdr_frames import FIRST_PASS_PIXELS, faithful_hdr, faithful_summary, first_pass
from layercam.pipelines.runner import Context, Stage, write_json
from layercam.io.hdr_set import HALF_MAX, HdrSet, write_hdr_set
from layercam.pipelines.windows.plan import area, fit_maps
from layercam.vision.scale import size_within
from layercam.pipelines import media
from layercam.pipelines.sharp import sharp_writer

CHECKPOINT_NAME = "checkpoint.pt"


def hdr_writer(ctx: Context, model, dest: Path, cache: Path, atlas=None) -> dict:
    """``hdr/``, ``preview.mp4``, ``hdr.mp4``; each frame's geometry handed to ``atlas`` (an
    :class:`~layercam.pipelines.atlas_export.AtlasSink`) when given."""
    from layercam.scene import render
    from layercam.io import VideoWriter

    stats, peak = first_pass(ctx, model)
    exrs = HdrSet(ctx.resolved.settings.export.half and peak <= HALF_MAX, ctx.say)
    (dest / "hdr").mkdir(exist_ok=True)
    infos, fits = [], None
    with VideoWriter(dest / "preview.mp4", fps=media.fps(ctx), audio=media.audio(ctx)) as preview:
        for t, hdr, info in faithful_hdr(ctx, model, ctx.frames_bar(), None if atlas is None else atlas.add):
            exrs.add(dest / "hdr" / f"frame_{t:05d}.exr", hdr)
            preview.add(render.tonemap_display(hdr, stats)[0])
            fit = info.pop("fit_map", None)
            if fit is not None and ctx.window is not None:  # how well a window's model reproduces
                                                            # each frame, per pixel (the join's
                                                            # weights)
                fits = fit_maps(cache, ctx.clip.T, size_within(fit.shape, FIRST_PASS_PIXELS)) if fits is None else fits
                fits[t] = area(fit, fits.shape[1:])
            infos.append(info)
    if fits is not None:
        fits.flush()
        del fits
    return {"frames": int(ctx.clip.T), "hdr_min": exrs.lo, "hdr_max": exrs.hi,
            "exr": "half" if exrs.half else "float32", "display": stats, **faithful_summary(infos),
            "hdr_video": hdr_video(ctx, model, exrs.paths, dest), "fps": media.fps(ctx),
            "sound": media.sound(ctx, preview)}


def hdr_video(ctx: Context, model, paths: list[Path], dest: Path) -> dict:
    """``hdr.mp4`` from the EXRs at ``paths`` in ``export.hdr_format`` (:mod:`layercam.io.hdr_video`),
    diffuse white (:func:`layercam.scene.render.white_radiance`) at ``export.nits_white``; with an ffmpeg
    that cannot write one, a warning naming what it lacks, and none (as ``hdr_format=none``)."""
    from layercam.io import read_exr
    from layercam.io.inputs import primaries_of
    from layercam.io.hdr_video import ANCHOR, MIN_SIDE, missing_for_hdr, write_hdr_video
    from layercam.io.ffmpeg import ffmpeg_exe
    from layercam.scene.render import white_radiance

    fmt = ctx.resolved.settings.export.hdr_format
    if fmt == "none":
        return {"format": "none"}
    missing = missing_for_hdr()
    if missing:
        ctx.warn(f"ffmpeg ({ffmpeg_exe()}) has no {missing}: hdr.mp4 is not written (as with "
                 "--hdr-format none); imageio-ffmpeg >= 0.8 ships an ffmpeg with it")
        return {"format": "none", "why": f"ffmpeg has no {missing}"}
    if min(ctx.clip.H, ctx.clip.W) < MIN_SIDE:
        ctx.warn(f"hdr.mp4 is not written: libx265 encodes frames of at least {MIN_SIDE} px a "
                 f"side, these are {ctx.clip.W}x{ctx.clip.H}")
        return {"format": "none", "why": f"frames below {MIN_SIDE} px"}
    prim = ctx.clip.meta.get("primaries") or primaries_of(None)
    white = white_radiance(model)
    info = write_hdr_video(dest / "hdr.mp4", lambda: (read_exr(p) for p in paths), media.fps(ctx),
                           fmt, white, ctx.resolved.settings.export.nits_white, prim["name"],
                           audio=media.audio(ctx), progress=ctx.progress)
    if info["audio"] and not info["audio"]["kept"]:
        ctx.warn(f"hdr.mp4 is written without the input's sound: {info['audio']['why']}")
    return {**info, "input_primaries": prim, "anchor": ANCHOR}


def fused_writer(ctx: Context, model, dest: Path, cache: Path) -> dict:
    from layercam.scene import render
    from layercam.io import write_png

    hw = (ctx.clip.H, ctx.clip.W)
    ref = reference_index(ctx.resolved.settings.export.reference, ctx.clip.T)
    _, hdr, info = next(faithful_hdr(ctx, model, [ref]))
    write_hdr_set([dest / "fused.exr"], [hdr], ctx.resolved.settings.export.half, ctx.say)
    np.save(cache / "fused.npy", hdr.astype(np.float32))
    if ctx.resolved.settings.model.tone_mapper == "fixed":  # one exposure: the sharp image as the
                                                            # camera would have recorded it
        png = render.render_frame(model, ref, hw, ("ldr",))["ldr"]
        how, stats = "fixed sRGB tone curve at the stack's exposure (input tonality)", None
    else:
        png, stats = render.tonemap_display(hdr)
        how = "Reinhard global tonemap + sRGB"
    write_png(dest / "fused.png", png, bit_depth=media.png_bits(ctx))
    return {"reference": ref, "reference_name": ctx.clip.names[ref], "png": how, "display": stats,
            "hdr_min": float(hdr.min()), "hdr_max": float(hdr.max()), **faithful_summary([info])}


def atlas_writer(ctx: Context, model, dest: Path, cache: Path, atlas=None) -> dict:
    """``atlases/``, ``alpha/``: closes ``atlas`` (fed by the HDR writer) or renders the frames' geometry."""
    from layercam.pipelines.atlas_export import export_atlases

    if atlas is not None:
        return {"atlas": atlas.close()}
    return {"atlas": export_atlases(model, dest, ctx.clip.frames, fps=media.fps(ctx), progress=ctx.progress,
                                    flow=ctx.flow)}


def crf_writer(ctx: Context, model, dest: Path, cache: Path) -> dict:
    """``crf.json`` (z = log2 r + log2 dt in stops -> value per channel) and ``crf.png``."""
    import torch

    from layercam.io.atomic import atomic_write
    from layercam.io.figures import crf_figure

    z = torch.linspace(-12, 12, 241)
    curve = model.tone.curve(z.to(next(model.parameters()).device)).float().cpu().numpy()
    write_json(dest / "crf.json",
               {"z_stops": z.tolist(), "r": curve[:, 0].tolist(), "g": curve[:, 1].tolist(),
                "b": curve[:, 2].tolist(), "kind": model.cfg.model.tone_mapper,
                "exposures_log2": model.exposure.values().detach().cpu().tolist()})
    fig = crf_figure(z.numpy(), curve)
    atomic_write(dest / "crf.png", lambda p: fig.savefig(p, format="png"))
    return {}


def psf_writer(ctx: Context, model, dest: Path, cache: Path) -> dict:
    from layercam.camera.blur import psf_summary

    if model.blur is None:
        return {"psf": None}
    psf = psf_summary(model.blur, (ctx.clip.H, ctx.clip.W))
    write_json(dest / "psf.json", {"frames": list(ctx.clip.names), **psf})
    return {"psf": psf}


def checkpoint_writer(ctx: Context, model, dest: Path, cache: Path) -> dict:
    from layercam.engine.checkpoint import save_run_model
    from layercam.pipelines.stages import model_meta

    meta = model_meta(ctx)
    if ctx.task == "fuse-stack":
        meta["reference"] = reference_index(ctx.resolved.settings.export.reference, ctx.clip.T)
    save_run_model(dest / CHECKPOINT_NAME, model, meta)
    return {}


# writer name -> (function, what it may write at the top of the run folder)
WRITERS = {
    "hdr": (hdr_writer, ["hdr", "preview.mp4", "hdr.mp4"]),
    "sharp": (sharp_writer, ["frames", "trust", "deblurred.mp4", "hdr"]),
    "fused": (fused_writer, ["fused.exr", "fused.png"]),
    "atlases": (atlas_writer, ["atlases", "alpha"]),
    "crf": (crf_writer, ["crf.json", "crf.png"]),
    "psf": (psf_writer, ["psf.json"]),
    "checkpoint": (checkpoint_writer, [CHECKPOINT_NAME]),
}
TASK_WRITERS = {"hdr-video": ("hdr",), "demo": ("hdr",), "deblur-video": ("sharp",), "fuse-stack": ("fused",)}
SHARING = ("hdr", "atlases")  # the first renders every frame and hands the second each frame's geometry
COMMON_WRITERS = ("atlases", "crf", "psf", "checkpoint")  # render writers run on the training
                                                          # device, these on the CPU from "crf" on
REPORT_NAME = "report.json"  # written by the task after its stages; set aside with the outputs it describes


def writers_for(task: str) -> tuple[str, ...]:
    return TASK_WRITERS.get(task, TASK_WRITERS["hdr-video"]) + COMMON_WRITERS


def outputs_for(task: str) -> list[str]:
    """Everything at the top of a run folder that a ``task`` export may have written."""
    names = [n for w in writers_for(task) for n in WRITERS[w][1]]
    return list(dict.fromkeys(names + [REPORT_NAME]))


def all_output_names() -> list[str]:
    """Every name an export may publish to the top of a run folder, for any task."""
    return list(dict.fromkeys(n for task in TASK_WRITERS for n in outputs_for(task) if n != REPORT_NAME))


class ExportStage(Stage):
    """Writes the run folder with the task's writers (this module's docstring)."""

    name = "export"
    deps = ("train",)
    # the last two: the sharp frames' trust window
    reads = ("export", "task", "static", "model.blur", "blur.max_offset")

    def output_names(self, ctx):
        return [n for n in outputs_for(ctx.task) if n != REPORT_NAME]

    def options(self, ctx):
        # a window's export keeps windows.plan.FIT_FILE (older ones: none); deblur-video's frames
        # are trusted per pixel (older ones: a check per frame)
        # two layers' mattes are voted along the flow (older ones: each its own frame's)
        fits = {"fits": "per pixel"} if ctx.window is not None else {}
        votes = {"mattes": "voted along the flow"} if ctx.resolved.settings.model.layers > 1 else {}
        return fits | votes | ({"sharp": "trusted per pixel"} if "sharp" in writers_for(ctx.task) else {})

    def run(self, ctx, out):
        dest = out  # published to the top of the run folder when the run ends
        model = ctx.model
        model.to(ctx.resolved.settings.train.device)  # render where it trained (GPU when there is one)
        summary: dict = {}
        names = writers_for(ctx.task)
        atlas = None
        if SHARING[0] in names and SHARING[1] in names:  # the HDR frames' renders give the atlases their geometry
            from layercam.pipelines.atlas_export import AtlasSink

            atlas = AtlasSink(model, dest, ctx.clip.frames, fps=media.fps(ctx), flow=ctx.flow)
        try:
            for name in names:
                if name == "crf":
                    model.cpu()
                fn = WRITERS[name][0]
                summary.update(fn(ctx, model, dest, out, atlas=atlas) if name in SHARING else fn(ctx, model, dest, out))
        except BaseException:
            if atlas is not None and atlas.open:
                atlas.abort()
            raise
        return summary

    def load(self, ctx, out, summary):
        from layercam.pipelines.results import ExportResult

        return ExportResult(summary, **kept_arrays(out))


def kept_arrays(out: Path) -> dict:
    """The arrays an export keeps in ``out`` for a scorer (:class:`~layercam.pipelines.results.ExportResult`)."""
    return {k: (out / f"{n}.npy" if (out / f"{n}.npy").exists() else None) for k,
            n in (("frames", "deblurred"), ("fused", "fused"))}
