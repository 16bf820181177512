"""``layercam bench --table blur``: the blur generator's numbers on synthetic scenes with ground truth.

Cases (``--cases``, default all):

* ``shake``: camera-shake clip (``synth.shake_blur``, blur paths up to :data:`SHAKE_BLUR_PX`);
  PSNR/SSIM of the deblurred frames and of the blurry input against the sharp frames, "raw" and
  "aligned" (each frame at its best shift within 3 px), and for the frame with the largest blur.
  Writes ``OUT/shake.json``.
* ``mfme-3``, ``mfme-9``: 3 focus x 3 exposure stack (``synth.mfme_stack``) trained on images 0, 4, 8
  (one per focus and exposure, as in the paper) or on all 9; PSNR-mu of the fused all-in-focus HDR
  against ground truth, next to the two-stage baseline (Laplacian-energy focus fusion per exposure +
  Debevec merge); with several ``seeds``, their mean and std. Writes ``OUT/mfme.json``.

Variants (``--variants``, default s5,s0,off for shake and s5,off for mfme): :data:`VARIANTS`; s5 = 3x3
patch with offsets up to 5 px, s0 = fixed 3x3 patch (learned weights only: the paper's s = 0
ablation), off = no blur generator. Runs in this process (``threads`` torch threads), run folders
under ``OUT/shake_<variant>`` and ``OUT/mfme_<images>_<variant>[_seed<k>]``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from layercam.core.errors import LayercamError

VARIANTS = {"off": {"blur": "off"}, "s0": {"blur": "3x3", "max_offset": 0.0},
            "s5": {"blur": "3x3", "max_offset": 5.0}, "s5n5": {"blur": "5x5", "max_offset": 5.0},
            "s5nf": {"blur": "3x3", "max_offset": 5.0, "flow_loss": False}}  # nf: no flow loss
DEFAULT_VARIANTS = {"shake": ["s5", "s0", "off"], "mfme": ["s5", "off"]}
CASES = ["shake", "mfme-3", "mfme-9"]
SHAKE_BLUR_PX = 8.0  # the shake clip's longest blur path (px)
SIZE, FRAMES = (64, 64), 8
QUICK_SIZE, QUICK_FRAMES = (32, 32), 4
QUICK = ["train.steps=20", "train.bootstrap_steps=2", "train.batch=512"]


def shake(out: Path, variants: list[str], preset: str, overrides: list[str], size: tuple[int, int],
          frames: int, progress: bool = True) -> dict:
    from layercam import synth
    from layercam.core.presets import load_config, model_overrides
    from layercam.io import Exposures
    from layercam.bench.evaluate import EvaluateStage
    from layercam.pipelines.tasks import run_task

    say = print if progress else (lambda *a, **k: None)
    scene = synth.shake_blur(frames=frames, size=size, max_blur_px=SHAKE_BLUR_PX, seed=0)
    exp = Exposures(np.zeros(frames), "none", None, "none", "single")
    lengths = scene.meta["blur_length"]
    big = int(np.argmax(lengths))
    say("blur lengths (px)", np.round(lengths, 2).tolist(), "largest: frame", big)
    res = {"blur_length": np.asarray(lengths).tolist(), "largest": big}
    for v in variants:
        cfg = load_config(preset, model_overrides(layers=1, **VARIANTS[v]) + overrides)
        t0 = time.time()
        ctx = run_task("deblur-video", scene.clip, exp, cfg, out / f"shake_{v}", progress=False,
                       extra_stages=[EvaluateStage(scene)])
        ev = ctx.results["evaluate"].summary
        pf, pa = ev["raw"]["per_frame"], ev["aligned"]["per_frame"]
        say(f"{v}: {time.time() - t0:.0f} s  raw: deblurred {ev['raw']['deblurred']} input {ev['raw']['input']}")
        say(f"    aligned: deblurred {ev['aligned']['deblurred']} input {ev['aligned']['input']}")
        say(f"    largest blur (frame {big}): raw {pf['deblurred'][big]} input {pf['input'][big]}; "
            f"aligned {pa['deblurred'][big]} input {pa['input'][big]}")
        res[v] = {"seconds": round(time.time() - t0, 1), **ev}
    return res


def mfme(out: Path, subsets: list[str], variants: list[str], seeds: list[int], preset: str,
         overrides: list[str], size: tuple[int, int], progress: bool = True) -> dict:
    from layercam import synth
    from layercam.core.presets import load_config, model_overrides
    from layercam.io import Exposures
    from layercam.io.clip import Clip
    from layercam.bench.evaluate import EvaluateStage
    from layercam.pipelines.tasks import run_task

    say = print if progress else (lambda *a, **k: None)
    scene = synth.mfme_stack(size=size, seed=0)
    ev, fidx = scene.meta["ev"], scene.meta["focus_index"]
    say("disc blur radius (plane x focus)", np.round(scene.meta["blur_radius"], 2).tolist())
    res = {}
    for sub in subsets:
        idx = [0, 4, 8] if sub == "3" else list(range(9))
        clip = Clip(scene.clip.frames[idx], "synthetic:mfme_stack",
                    [scene.clip.names[i] for i in idx], meta={"kind": "synthetic"})
        e = Exposures(ev[idx] - ev[idx].min(), "none", None, "times", "synthetic: known times")
        truth = {"focus_index": fidx[idx], "times": scene.exposure_times[idx],
                 "full_stack": (scene.clip.frames, scene.exposure_times, fidx)}
        for v in variants:
            # seed 0 keeps the plain name
            key = {seed: f"{sub}_{v}" + (f"_seed{seed}" if seed else "") for seed in seeds}
            for seed in seeds:
                cfg = load_config(preset, model_overrides(layers=1, **VARIANTS[v]) + overrides + [f"train.seed={seed}"])
                t0 = time.time()
                ctx = run_task("fuse-stack", clip, e, cfg, out / f"mfme_{key[seed]}", progress=False,
                               extra_stages=[EvaluateStage(scene, **truth)])
                r = ctx.results["evaluate"].summary
                say(f"{sub} images, {v}, seed {seed}: {time.time() - t0:.0f} s  layercam {r['metrics']}", flush=True)
                for k, b in r["baselines"].items():
                    say(f"    {k}: {b}")
                res[key[seed]] = {"seconds": round(time.time() - t0, 1), **r}
            if len(seeds) > 1:
                vals = [res[key[s]]["metrics"]["psnr_mu"] for s in seeds]
                res[f"{sub}_{v}_seeds"] = {"seeds": seeds, "psnr_mu": vals,
                                           "mean": float(np.mean(vals)), "std": float(np.std(vals))}
                say(f"{sub} images, {v}: PSNR-mu over seeds {seeds}: mean {np.mean(vals):.2f}, std {np.std(vals):.2f}")
    return res


def run_blur(out: Path, cases: list[str] | None = None, variants: list[str] | None = None,
             seeds: list[int] | None = None, preset: str = "fast",
             overrides: list[str] | None = None, size: tuple[int, int] | None = None,
             frames: int | None = None, quick: bool = False,
             threads: int = 1, progress: bool = True) -> dict:
    """The cases asked for; ``{"shake": ..., "mfme": ...}`` as written to ``OUT/shake.json`` and ``OUT/mfme.json``.
    ``size`` (H, W) and ``frames`` (shake) default to 64x64 and 8 (``quick``: 32x32 and 4, a few steps)."""
    import torch

    from layercam.io.atomic import atomic_write

    cases = cases or CASES
    bad = [c for c in cases if c not in CASES] + [v for v in variants or [] if v not in VARIANTS]
    if bad:
        raise LayercamError(f"--table blur: unknown {bad[0]!r} (cases: {', '.join(CASES)}; "
                            f"variants: {', '.join(VARIANTS)})")
    size = size or (QUICK_SIZE if quick else SIZE)
    frames = frames or (QUICK_FRAMES if quick else FRAMES)
    overrides = (QUICK if quick else []) + list(overrides or [])
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(threads)
    res = {}
    if "shake" in cases:
        res["shake"] = shake(out, variants or DEFAULT_VARIANTS["shake"], preset, overrides, size, frames, progress)
    subsets = [c.split("-")[1] for c in cases if c.startswith("mfme-")]
    if subsets:
        res["mfme"] = mfme(out, subsets, variants or DEFAULT_VARIANTS["mfme"], seeds or [0], preset,
                           overrides, size, progress)
    for what, r in res.items():
        atomic_write(out / f"{what}.json", lambda p, r=r: p.write_text(json.dumps(r, indent=1, default=str)))
    return res
