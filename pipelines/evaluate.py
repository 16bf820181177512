"""Scores an exported run against ground truth (synthetic scenes) next to classical baselines."""

from __future__ import annotations

import time

import numpy as np

from layercam.pipelines.runner import Stage
from layercam.pipelines.stages import load_flow


def read_hdr_frames(run_dir, n: int) -> np.ndarray:
    from layercam.io import read_exr

    return np.stack([read_exr(run_dir / "hdr" / f"frame_{t:05d}.exr") for t in range(n)])


class EvaluateStage(Stage):
    """PSNR-mu / PSNR-L / SSIM-mu of the exported HDR against ``ctx.extra["scene"].hdr``, and the
    same for OpenCV Debevec (calibrate + merge of each frame with its DIS-aligned neighbour)."""

    name = "evaluate"
    deps = ("export", "flow")
    version = 1

    def key_material(self, ctx):
        return {"baselines": ctx.extra.get("baselines", ["debevec"])}

    def run(self, ctx, out):
        from layercam import metrics

        scene = ctx.extra["scene"]
        gt = scene.hdr
        pred = read_hdr_frames(ctx.run_dir, ctx.clip.T)
        res = {"metrics": metrics.hdr_metrics(pred, gt), "baselines": {}}
        wall_model = sum(v.get("seconds", 0) or v.get("original_seconds", 0) or 0 for k, v in ctx.times.items() if k != "evaluate")
        res["metrics"]["wall_s"] = round(wall_model, 2)
        if "debevec" in ctx.extra.get("baselines", ["debevec"]) and ctx.clip.T > 1 and ctx.exposures.count_distinct > 1:
            from layercam.baselines import debevec_video

            fl = load_flow(ctx)
            t0 = time.perf_counter()
            base = debevec_video(ctx.clip.frames, np.exp2(ctx.exposures.log2_dt), fl["fw"].astype(np.float32), fl["bw"].astype(np.float32))
            secs = time.perf_counter() - t0 + ctx.times.get("flow", {}).get("seconds", 0.0)
            res["baselines"]["debevec"] = {**metrics.hdr_metrics(base, gt), "wall_s": round(secs, 2)}
        return res
