"""Export stages of the blur tasks (``deblur-video``, ``fuse-stack``) and their scoring against
synthetic ground truth.

Both tasks train the same model (scene + blur generator + tone mapper) with the same stages as
``hdr-video``; only what is written at the end differs:

* :class:`DeblurExportStage` renders every frame through the tone mapper at the frame's own
  exposure with the blur generator dropped: sharp frames in the input's tonality
  (``frames/frame_00000.png``, ``deblurred.mp4``), plus linear HDR EXRs when exposures vary.
* :class:`FuseExportStage` renders the scene for one reference view with the whole camera dropped:
  the all-in-focus linear HDR ``fused.exr`` and a tonemapped ``fused.png`` (for a single-exposure
  stack, whose tone mapper is the fixed sRGB curve, the PNG is the sharp image in the input's
  tonality instead).

Both write ``crf.json``/``crf.png``, ``checkpoint.pt`` (what ``layercam render`` reads) and a
summary of the learned PSF per frame (:func:`psf_summary`) into the report.

:class:`DeblurEvaluateStage` and :class:`FuseEvaluateStage` score a run on a ``layercam.synth``
scene passed as ``ctx.extra["scene"]`` (used by the checks and benchmarks, not by the CLI).
"""

from __future__ import annotations

import time

import numpy as np

from layercam.errors import LayercamError
from layercam.pipelines.runner import Context, Stage, set_aside_previous, write_json
from layercam.pipelines.stages import load_trained, resolve_device, write_crf, write_hdr_set

DEBLUR_OUTPUTS = ["frames", "deblurred.mp4", "hdr", "crf.json", "crf.png", "checkpoint.pt", "report.json", "psf.json"]
FUSE_OUTPUTS = ["fused.exr", "fused.png", "crf.json", "crf.png", "checkpoint.pt", "report.json", "psf.json"]


def exposures_vary(ctx: Context) -> bool:
    return ctx.exposures.count_distinct > 1 or ctx.exposures.learn != "none"


def resolve_reference(ref, n: int) -> int:
    """The image a stack is fused into: "middle" (default), "first", "last" or an index (negative
    counts from the end) among ``n`` images."""
    named = {"middle": (n - 1) // 2, "first": 0, "last": n - 1}
    if ref is None:
        ref = "middle"
    if isinstance(ref, str) and ref.strip().lower() in named:
        return named[ref.strip().lower()]
    try:
        i = int(ref)
    except (TypeError, ValueError):
        raise LayercamError(f"reference must be middle, first, last or an image index, got {ref!r}") from None
    if not -n <= i < n:
        raise LayercamError(f"reference image {i} is out of range for {n} images")
    return i % n


def reference_frame(ctx: Context) -> int:
    """:func:`resolve_reference` of ``ctx.extra["reference"]`` for this clip."""
    return resolve_reference(ctx.extra.get("reference", "middle"), ctx.clip.T)


def psf_summary(model, hw: tuple[int, int], grid: int = 24) -> dict | None:
    """Per frame, the learned PSF on a ``grid x grid`` lattice of pixels, averaged: ``spread_px``
    (weighted RMS distance of the samples from their weighted centre: 0 for a sharp frame, about
    ``L / sqrt(12)`` for a straight blur of length ``L``), ``centre_weight`` and ``shift_px`` (the
    length of the PSF's weighted centre). The lattice leaves out a border as wide as the patch can
    reach (``n // 2 + 2 s`` px, at most a quarter of the frame): there samples fall outside the
    frame and nothing constrains the PSF. None when the model has no blur generator."""
    import torch

    from layercam.data import normalise_xy

    if model.blur is None:
        return None
    h, w = hw
    reach = model.blur.n // 2 + 2 * model.blur.max_offset
    my, mx = (int(min(reach, (v - 1) // 4)) for v in (h, w))
    ys = torch.linspace(my, h - 1 - my, min(grid, h - 2 * my)).round()
    xs = torch.linspace(mx, w - 1 - mx, min(grid, w - 2 * mx)).round()
    yy, xx = torch.meshgrid(ys, xs, indexing="ij")
    xy = normalise_xy(xx.flatten(), yy.flatten(), w, h)
    dev = next(model.parameters()).device
    xy = xy.to(dev)
    rows = {"spread_px": [], "centre_weight": [], "shift_px": []}
    with torch.no_grad():
        for t in range(model.blur.n_frames):
            disp, wts = model.blur.kernels(xy, torch.full((xy.shape[0],), t, dtype=torch.long, device=dev))
            centre = (wts[:, :, None] * disp).sum(1)
            spread = ((wts * ((disp - centre[:, None]) ** 2).sum(-1)).sum(1)).sqrt()
            rows["spread_px"].append(round(float(spread.mean()), 4))
            rows["centre_weight"].append(round(float(wts[:, model.blur.K // 2].mean()), 4))
            rows["shift_px"].append(round(float(centre.norm(dim=1).mean()), 4))
    return rows


def _finish_export(ctx: Context, model, meta: dict, extra_meta: dict | None = None) -> dict:
    from layercam.checkpoint import save_run_model

    run = ctx.run_dir
    model.cpu()
    write_crf(run, model)
    psf = psf_summary(model, (ctx.clip.H, ctx.clip.W))
    if psf is not None:
        write_json(run / "psf.json", {"frames": list(ctx.clip.names), **psf})
    save_run_model(run / "checkpoint.pt", model, {**meta, **(extra_meta or {})})
    (run / "export_key.txt").write_text(ctx.keys["export"])
    return {"psf": psf}


class DeblurExportStage(Stage):
    """deblur-video: sharp frames in the input's tonality (the tone mapper at each frame's own
    exposure, the blur generator dropped), ``deblurred.mp4``, and ``hdr/`` EXRs when exposures vary."""

    name = "export"
    deps = ("train",)
    version = 1
    outputs = DEBLUR_OUTPUTS

    def key_material(self, ctx):
        return {**ctx.cfg.section_dict("export"), "kind": "deblur"}

    def run(self, ctx, out):
        from layercam.io import write_png, write_video
        from layercam.progress import bar as progress_bar
        from layercam.render import render_frame

        run = ctx.run_dir
        set_aside_previous(run, self.outputs, ctx.keys[self.name], ctx.say)
        model, meta = load_trained(ctx)
        model.to(resolve_device(ctx.cfg.train.device))  # render where it trained
        hw = (ctx.clip.H, ctx.clip.W)
        with_hdr = exposures_vary(ctx)
        (run / "frames").mkdir(exist_ok=True)
        if with_hdr:
            (run / "hdr").mkdir(exist_ok=True)
        bits = 16 if ctx.clip.bit_depth > 8 else 8
        frames, hdr = [], []
        for t in progress_bar(range(ctx.clip.T), desc="export", unit="frame", enabled=ctx.progress):
            ldr = render_frame(model, t, hw, ctx.cfg.export.chunk, what="ldr", blur=False)["image"]
            if not np.isfinite(ldr).all():
                raise LayercamError(f"frame {t}: the model rendered non-finite values; not writing it")
            write_png(run / "frames" / f"frame_{t:05d}.png", ldr, bit_depth=bits)
            frames.append(ldr)
            if with_hdr:
                hdr.append(render_frame(model, t, hw, ctx.cfg.export.chunk)["image"])
        write_hdr_set([run / "hdr" / f"frame_{t:05d}.exr" for t in range(len(hdr))], hdr, ctx.cfg.export.half, ctx.say)
        hdr_max = max((float(h.max()) for h in hdr), default=0.0)
        frames = np.stack(frames)
        np.save(out / "deblurred.npy", frames.astype(np.float32))
        fps = ctx.cfg.export.preview_fps or float(ctx.clip.fps or 24.0)
        write_video(run / "deblurred.mp4", frames, fps=fps)
        extra = _finish_export(ctx, model, meta)
        return {"frames": int(ctx.clip.T), "hdr": with_hdr, "hdr_max": hdr_max, "png_bits": bits, **extra}

    def load(self, ctx, out, summary):
        return {**summary, "frames_path": str(out / "deblurred.npy")}


class FuseExportStage(Stage):
    """fuse-stack: the scene rendered for the reference view with the camera dropped:
    ``fused.exr`` (all-in-focus linear HDR) and ``fused.png``."""

    name = "export"
    deps = ("train",)
    version = 1
    outputs = FUSE_OUTPUTS

    def key_material(self, ctx):
        return {**ctx.cfg.section_dict("export"), "kind": "fuse", "reference": reference_frame(ctx)}

    def run(self, ctx, out):
        from layercam.io import write_png
        from layercam.render import render_frame, tonemap_display

        run = ctx.run_dir
        set_aside_previous(run, self.outputs, ctx.keys[self.name], ctx.say)
        model, meta = load_trained(ctx)
        model.to(resolve_device(ctx.cfg.train.device))  # render where it trained
        hw = (ctx.clip.H, ctx.clip.W)
        ref = reference_frame(ctx)
        hdr = render_frame(model, ref, hw, ctx.cfg.export.chunk)["image"]
        write_hdr_set([run / "fused.exr"], [hdr], ctx.cfg.export.half, ctx.say)
        np.save(out / "fused.npy", hdr.astype(np.float32))
        if ctx.cfg.model.tone_mapper == "fixed":
            # one exposure: show the sharp image as the camera would have recorded it
            png = render_frame(model, ref, hw, ctx.cfg.export.chunk, what="ldr", blur=False)["image"]
            how = "fixed sRGB tone curve at the stack's exposure (input tonality)"
            stats = None
        else:
            png, stats = tonemap_display(hdr)
            how = "Reinhard global tonemap + sRGB"
        write_png(run / "fused.png", png, bit_depth=16 if ctx.clip.bit_depth > 8 else 8)
        extra = _finish_export(ctx, model, meta, {"reference": ref})
        return {
            "reference": ref, "reference_name": ctx.clip.names[ref], "png": how, "display": stats,
            "hdr_min": float(hdr.min()), "hdr_max": float(hdr.max()), **extra,
        }

    def load(self, ctx, out, summary):
        return {**summary, "fused_path": str(out / "fused.npy")}


EXPORTS = {"deblur-video": DeblurExportStage, "fuse-stack": FuseExportStage}


# -- scoring on synthetic scenes ------------------------------------------------------------------
def _translate(img: np.ndarray, dx: float, dy: float) -> np.ndarray:
    import cv2

    m = np.array([[1, 0, dx], [0, 1, dy]], np.float64)
    return cv2.warpAffine(img, m, img.shape[1::-1], flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101)


def best_shift(pred: np.ndarray, gt: np.ndarray, crop: int, max_shift: float = 3.0) -> tuple[np.ndarray, tuple[float, float]]:
    """Translate ``pred (H, W, 3)`` by the shift (within ``max_shift`` px, 0.25 px steps) that
    minimises its squared error to ``gt`` inside a ``crop``-pixel border: a deblurred frame may show
    any instant of the exposure, and the blurry frame its blur's centre, so both are compared at
    their best shift."""
    c = (slice(crop, pred.shape[0] - crop), slice(crop, pred.shape[1] - crop))

    def err(dx, dy):
        return float(((_translate(pred, dx, dy)[c] - gt[c]) ** 2).mean())

    n = int(max_shift)
    best = min(((dx, dy) for dx in range(-n, n + 1) for dy in range(-n, n + 1)), key=lambda d: err(*d))
    fine = [(best[0] + a / 4, best[1] + b / 4) for a in range(-3, 4) for b in range(-3, 4)]
    fine = [d for d in fine if abs(d[0]) <= max_shift and abs(d[1]) <= max_shift]
    dx, dy = min(fine, key=lambda d: err(*d))
    return _translate(pred, dx, dy), (float(dx), float(dy))


def score_frames(pred: np.ndarray, gt: np.ndarray, crop: int, align: bool) -> list[dict]:
    """Per frame ``{"psnr", "ssim"}`` of LDR ``pred`` against ``gt`` (both ``(T, H, W, 3)``), with a
    ``crop``-pixel border left out; ``align`` first moves each frame by its :func:`best_shift`."""
    from layercam import metrics

    rows = []
    for p, g in zip(pred, gt):
        shift = (0.0, 0.0)
        if align:
            p, shift = best_shift(p, g, max(crop, 4))
        c = (slice(crop, p.shape[0] - crop), slice(crop, p.shape[1] - crop)) if crop else (slice(None), slice(None))
        m = metrics.ldr_metrics(np.clip(p[c], 0, 1), g[c])
        rows.append({"psnr": round(m["psnr"], 3), "ssim": round(m["ssim"], 4), "shift": [round(shift[0], 2), round(shift[1], 2)]})
    return rows


class DeblurEvaluateStage(Stage):
    """PSNR/SSIM of the deblurred frames against ``scene.sharp_ldr``, next to the blurry input's;
    a border of ``ctx.extra["crop"]`` px (default 4) is left out; "raw" as rendered, and "aligned":
    each frame (deblurred and input alike) at its best shift within 3 px (:func:`best_shift`)."""

    name = "evaluate"
    deps = ("export",)
    version = 2

    def key_material(self, ctx):
        return {"crop": ctx.extra.get("crop", 4)}

    def run(self, ctx, out):
        scene = ctx.extra["scene"]
        crop = int(ctx.extra.get("crop", 4))
        pred = np.load(ctx.results["export"]["frames_path"])
        gt, blurry = scene.sharp_ldr, ctx.clip.frames
        res = {"crop": crop}
        for align in (False, True):
            key = "aligned" if align else "raw"
            d, b = score_frames(pred, gt, crop, align), score_frames(blurry, gt, crop, align)
            res[key] = {
                "deblurred": {"psnr": float(np.mean([r["psnr"] for r in d])), "ssim": float(np.mean([r["ssim"] for r in d]))},
                "input": {"psnr": float(np.mean([r["psnr"] for r in b])), "ssim": float(np.mean([r["ssim"] for r in b]))},
                "per_frame": {"deblurred": d, "input": b},
            }
        lengths = scene.meta.get("blur_length")
        res["blur_length"] = None if lengths is None else [round(float(v), 3) for v in lengths]
        res["metrics"] = res["raw"]["deblurred"]
        return res


class FuseEvaluateStage(Stage):
    """PSNR-mu / PSNR-L / SSIM-mu of ``fused.exr`` against ``scene.allfocus_hdr``, next to
    ``baselines.two_stage_mfme`` (Laplacian focus fusion per exposure, then Debevec) on the same
    images and, when ``ctx.extra["full_stack"] = (images, times, focus_index)`` is given, on that."""

    name = "evaluate"
    deps = ("export",)
    version = 1

    def key_material(self, ctx):
        fs = ctx.extra.get("full_stack")
        return {"focus_index": [int(v) for v in ctx.extra.get("focus_index", [])], "full": None if fs is None else int(len(fs[0]))}

    def run(self, ctx, out):
        from layercam import metrics
        from layercam.baselines import two_stage_mfme

        scene = ctx.extra["scene"]
        gt = scene.allfocus_hdr
        pred = np.load(ctx.results["export"]["fused_path"])
        res = {"metrics": metrics.hdr_metrics(pred, gt), "baselines": {}}
        res["metrics"]["wall_s"] = round(sum(v.get("seconds", 0) or v.get("original_seconds", 0) or 0 for k, v in ctx.times.items() if k != "evaluate"), 2)
        sets = {}
        if "focus_index" in ctx.extra:
            times = ctx.extra.get("times", np.exp2(ctx.exposures.log2_dt))
            sets[f"two_stage_mfme ({ctx.clip.T} images)"] = (ctx.clip.frames, times, ctx.extra["focus_index"])
        if ctx.extra.get("full_stack") is not None:
            imgs, times, fidx = ctx.extra["full_stack"]
            sets[f"two_stage_mfme ({len(imgs)} images)"] = (imgs, times, fidx)
        for name, (imgs, times, fidx) in sets.items():
            t0 = time.perf_counter()
            base = two_stage_mfme(imgs, times, fidx)
            res["baselines"][name] = {**metrics.hdr_metrics(base, gt), "wall_s": round(time.perf_counter() - t0, 2)}
        return res
