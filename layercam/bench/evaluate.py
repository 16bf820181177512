"""The evaluate stage: a run scored against the ground truth of a ``layercam.synth`` scene
(:attr:`EvaluateStage.scene`) next to the classical baselines, by the scorer of its task
(:data:`SCORERS`). Used by ``demo``, ``layercam bench`` (its synthetic tables) and the tests, not by the other commands.

* ``hdr``: PSNR-mu / PSNR-L / SSIM-mu of the exported ``hdr/`` frames against ``scene.hdr``, and the
  same for OpenCV Debevec (calibrate + merge of each frame with its DIS-aligned neighbour) unless
  ``baselines`` leaves it out.
* ``deblur``: PSNR / SSIM of the sharp frames against ``scene.sharp_ldr``, next to the blurry
  input's; a border of ``crop`` px is left out; "raw" as rendered, and "aligned": each frame
  (deblurred and input alike) at its best shift within 3 px (:func:`layercam.core.frame_metrics.best_shift`).
* ``fused``: PSNR-mu / PSNR-L / SSIM-mu of ``fused.exr`` against ``scene.allfocus_hdr``, next to
  ``baselines.two_stage_mfme`` (Laplacian focus fusion per exposure, then Debevec) on the same
  images (when ``focus_index`` is given, with ``times`` or the run's exposures) and, when
  ``full_stack = (images, times, focus_index)`` is given, on that.
"""

from __future__ import annotations

import time

import numpy as np

from layercam.pipelines.runner import Context, Stage


def read_hdr_frames(run_dir, n: int) -> np.ndarray:
    from layercam.io import read_exr

    return np.stack([read_exr(run_dir / "hdr" / f"frame_{t:05d}.exr") for t in range(n)])


def model_wall_s(ctx: Context) -> float:
    """Seconds the run's stages took (their first run, for cached ones), evaluation left out."""
    return round(sum(v.get("seconds", 0) or v.get("original_seconds", 0) or 0 for k,
                     v in ctx.times.items() if k != "evaluate"), 2)


def hdr_key(ctx: Context, ev: "EvaluateStage") -> dict:
    return {"baselines": list(ev.baselines)}


def score_hdr(ctx: Context, ev: "EvaluateStage") -> dict:
    from layercam.core import metrics

    gt = ev.scene.hdr
    res = {"metrics": {**metrics.hdr_metrics(read_hdr_frames(ctx.dirs["export"], ctx.clip.T), gt),
                       "wall_s": model_wall_s(ctx)}, "baselines": {}}
    if "debevec" in ev.baselines and ctx.clip.T > 1 and ctx.exposures.count_distinct > 1:
        from layercam.bench.baselines import debevec_video
        from layercam.vision.flow_store import at_frame_size

        fl = at_frame_size(ctx.flow, (ctx.clip.H, ctx.clip.W), ("fw", "bw"))
        t0 = time.perf_counter()
        base = debevec_video(ctx.clip.frames, np.exp2(ctx.exposures.log2_dt),
                             np.asarray(fl.fw, np.float32), np.asarray(fl.bw, np.float32))
        secs = time.perf_counter() - t0 + ctx.times.get("flow", {}).get("seconds", 0.0)
        res["baselines"]["debevec"] = {**metrics.hdr_metrics(base, gt), "wall_s": round(secs, 2)}
    return res


def deblur_key(ctx: Context, ev: "EvaluateStage") -> dict:
    return {"crop": ev.crop}


def score_deblur(ctx: Context, ev: "EvaluateStage") -> dict:
    from layercam.core.frame_metrics import score_frames

    scene, crop = ev.scene, int(ev.crop)
    pred = np.load(ctx.results["export"].frames)
    gt, blurry = scene.sharp_ldr, ctx.clip.frames
    res = {"crop": crop}
    for align in (False, True):
        d, b = score_frames(pred, gt, crop, align), score_frames(blurry, gt, crop, align)
        mean = lambda rows: {"psnr": float(np.mean([r["psnr"] for r in rows])),
                             "ssim": float(np.mean([r["ssim"] for r in rows]))}  # noqa: E731
        res["aligned" if align else "raw"] = {"deblurred": mean(d), "input": mean(b),
                                              "per_frame": {"deblurred": d, "input": b}}
    lengths = scene.meta.get("blur_length")
    res["blur_length"] = None if lengths is None else [round(float(v), 3) for v in lengths]
    res["metrics"] = res["raw"]["deblurred"]
    return res


def fused_key(ctx: Context, ev: "EvaluateStage") -> dict:
    fs = ev.full_stack
    return {"focus_index": [int(v) for v in (ev.focus_index if ev.focus_index is not None else [])],
            "full": None if fs is None else int(len(fs[0]))}


def score_fused(ctx: Context, ev: "EvaluateStage") -> dict:
    from layercam.core import metrics
    from layercam.bench.baselines import two_stage_mfme

    gt = ev.scene.allfocus_hdr
    pred = np.load(ctx.results["export"].fused)
    res = {"metrics": {**metrics.hdr_metrics(pred, gt), "wall_s": model_wall_s(ctx)}, "baselines": {}}
    sets = {}
    if ev.focus_index is not None:
        times = ev.times if ev.times is not None else np.exp2(ctx.exposures.log2_dt)
        sets[f"two_stage_mfme ({ctx.clip.T} images)"] = (ctx.clip.frames, times, ev.focus_index)
    if ev.full_stack is not None:
        imgs, times, fidx = ev.full_stack
        sets[f"two_stage_mfme ({len(imgs)} images)"] = (imgs, times, fidx)
    for name, (imgs, times, fidx) in sets.items():
        t0 = time.perf_counter()
        base = two_stage_mfme(imgs, times, fidx)
        res["baselines"][name] = {**metrics.hdr_metrics(base, gt), "wall_s": round(time.perf_counter() - t0, 2)}
    return res


# scorer name -> (key material, scorer); tasks -> scorer
SCORERS = {"hdr": (hdr_key, score_hdr), "deblur": (deblur_key, score_deblur), "fused": (fused_key, score_fused)}
TASK_SCORERS = {"hdr-video": "hdr", "demo": "hdr", "deblur-video": "deblur", "fuse-stack": "fused"}


class EvaluateStage(Stage):
    """Scores the exported run against ``scene`` (a ``layercam.synth.SynthScene``) with its task's
    scorer (this module's docstring); the other arguments are the scorers' options."""

    name = "evaluate"
    deps = ("flow", "export")

    def __init__(self, scene, *, baselines=("debevec",), crop: int = 4, focus_index=None, times=None, full_stack=None):
        self.scene, self.baselines, self.crop = scene, tuple(baselines), crop
        self.focus_index, self.times, self.full_stack = focus_index, times, full_stack

    def options(self, ctx):
        scorer = TASK_SCORERS[ctx.task]
        return {"scorer": scorer, **SCORERS[scorer][0](ctx, self)}

    def run(self, ctx, out):
        return SCORERS[TASK_SCORERS[ctx.task]][1](ctx, self)

    def load(self, ctx, out, summary):
        from layercam.pipelines.results import EvaluateResult

        return EvaluateResult(summary)
