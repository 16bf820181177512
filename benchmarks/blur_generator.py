"""The blur generator's numbers on synthetic scenes with ground truth (issue 4).

    python benchmarks/blur_generator.py shake [--size 64 --frames 8 --blur 8 --variants s5,s0,off]
    python benchmarks/blur_generator.py mfme  [--size 64 --subsets 3,9 --variants s5,off --seeds 0,1,2]

shake: camera-shake clip (``synth.shake_blur``); PSNR/SSIM of the deblurred frames and of the blurry
input against the sharp frames, "raw" and "aligned" (each frame at its best shift within 3 px), and
for the frame with the largest blur; variants: s5 = 3x3 patch with offsets up to 5 px, s0 = fixed
3x3 patch (learned weights only: the paper's s = 0 ablation), off = no blur generator.
mfme: 3 focus x 3 exposure stack (``synth.mfme_stack``) trained on images 0, 4, 8 (one per focus
and exposure, as in the paper) or on all 9; PSNR-mu of the fused all-in-focus HDR against ground
truth, next to the two-stage baseline (Laplacian-energy focus fusion per exposure + Debevec merge).
Writes OUT/{shake,mfme}.json. One torch thread per process.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from layercam import synth
from layercam.core.presets import load_config, model_overrides
from layercam.io import Exposures
from layercam.io.clip import Clip
from layercam.pipelines.evaluate import EvaluateStage
from layercam.pipelines.tasks import run_task

VARIANTS = {"off": {"blur": "off"}, "s0": {"blur": "3x3", "max_offset": 0.0}, "s5": {"blur": "3x3", "max_offset": 5.0}, "s5n5": {"blur": "5x5", "max_offset": 5.0},
            "s5nf": {"blur": "3x3", "max_offset": 5.0, "flow_loss": False}}  # nf: no flow loss


def shake(a) -> dict:
    scene = synth.shake_blur(frames=a.frames, size=(a.size, a.size), max_blur_px=a.blur, seed=0)
    exp = Exposures(np.zeros(a.frames), "none", None, "none", "single")
    lengths = scene.meta["blur_length"]
    big = int(np.argmax(lengths))
    print("blur lengths (px)", np.round(lengths, 2).tolist(), "largest: frame", big)
    out = {"blur_length": np.asarray(lengths).tolist(), "largest": big}
    for v in a.variants.split(","):
        cfg = load_config(a.preset, model_overrides(layers=1, **VARIANTS[v]) + a.set)
        t0 = time.time()
        ctx = run_task("deblur-video", scene.clip, exp, cfg, a.out / f"shake_{v}", progress=False,
                       extra_stages=[EvaluateStage(scene)])
        ev = ctx.results["evaluate"].summary
        pf, pa = ev["raw"]["per_frame"], ev["aligned"]["per_frame"]
        print(f"{v}: {time.time() - t0:.0f} s  raw: deblurred {ev['raw']['deblurred']} input {ev['raw']['input']}")
        print(f"    aligned: deblurred {ev['aligned']['deblurred']} input {ev['aligned']['input']}")
        print(f"    largest blur (frame {big}): raw {pf['deblurred'][big]} input {pf['input'][big]}; aligned {pa['deblurred'][big]} input {pa['input'][big]}")
        out[v] = {"seconds": round(time.time() - t0, 1), **ev}
    return out


def mfme(a) -> dict:
    scene = synth.mfme_stack(size=(a.size, a.size), seed=0)
    ev, fidx = scene.meta["ev"], scene.meta["focus_index"]
    print("disc blur radius (plane x focus)", np.round(scene.meta["blur_radius"], 2).tolist())
    out = {}
    for sub in a.subsets.split(","):
        idx = [0, 4, 8] if sub == "3" else list(range(9))
        clip = Clip(scene.clip.frames[idx], "synthetic:mfme_stack", [scene.clip.names[i] for i in idx], meta={"kind": "synthetic"})
        e = Exposures(ev[idx] - ev[idx].min(), "none", None, "times", "synthetic: known times")
        truth = {"focus_index": fidx[idx], "times": scene.exposure_times[idx], "full_stack": (scene.clip.frames, scene.exposure_times, fidx)}
        for v in a.variants.split(","):
            key = {seed: f"{sub}_{v}" + (f"_seed{seed}" if seed else "") for seed in a.seeds}  # seed 0 keeps the plain name
            for seed in a.seeds:
                cfg = load_config(a.preset, model_overrides(layers=1, **VARIANTS[v]) + a.set + [f"train.seed={seed}"])
                t0 = time.time()
                ctx = run_task("fuse-stack", clip, e, cfg, a.out / f"mfme_{key[seed]}", progress=False,
                               extra_stages=[EvaluateStage(scene, **truth)])
                r = ctx.results["evaluate"].summary
                print(f"{sub} images, {v}, seed {seed}: {time.time() - t0:.0f} s  layercam {r['metrics']}", flush=True)
                for k, b in r["baselines"].items():
                    print(f"    {k}: {b}")
                out[key[seed]] = {"seconds": round(time.time() - t0, 1), **r}
            if len(a.seeds) > 1:
                vals = [out[key[s]]["metrics"]["psnr_mu"] for s in a.seeds]
                out[f"{sub}_{v}_seeds"] = {"seeds": a.seeds, "psnr_mu": vals, "mean": float(np.mean(vals)), "std": float(np.std(vals))}
                print(f"{sub} images, {v}: PSNR-mu over seeds {a.seeds}: mean {np.mean(vals):.2f}, std {np.std(vals):.2f}")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", choices=["shake", "mfme"])
    ap.add_argument("--out", type=Path, default=Path("runs/blur_bench"))
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--blur", type=float, default=8.0, help="shake: longest blur path (px)")
    ap.add_argument("--subsets", default="3,9")
    ap.add_argument("--variants", default=None, help="comma-separated: " + ", ".join(VARIANTS))
    ap.add_argument("--preset", default="fast")
    ap.add_argument("--seeds", default="0", help="mfme: comma-separated training seeds (mean and std reported)")
    ap.add_argument("--set", action="append", default=[])
    a = ap.parse_args()
    a.variants = a.variants or ("s5,s0,off" if a.what == "shake" else "s5,off")
    a.seeds = [int(v) for v in a.seeds.split(",")]
    torch.set_num_threads(1)
    a.out.mkdir(parents=True, exist_ok=True)
    res = shake(a) if a.what == "shake" else mfme(a)
    (a.out / f"{a.what}.json").write_text(json.dumps(res, indent=1, default=str))


if __name__ == "__main__":
    main()
