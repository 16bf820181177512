"""``layercam bench --table layers``: the layered scene on real footage, scored against ground truth.

Every ``layers_davis_*`` clip under ``--data`` (DAVIS clips with per-frame foreground masks in
``masks_gt/``) runs as ``layercam hdr-video FRAMES --exposures none --resize R`` twice: with its
masks given (``--masks``, variant "masks") and without (variant "motion": the foreground is found by
the motion bootstrap). Each run is its own process (one torch thread unless told otherwise) and
keeps its run folder under ``OUT/runs/``; a finished job leaves ``OUT/results/<clip>-<variant>.json``
and is not run again (delete the file to re-measure), so an interrupted benchmark resumes.

Per run: the layers the analysis chose; the foreground alpha's IoU against the true masks (alpha >
0.5, per frame, then the mean); the bootstrap masks' IoU (variant "motion"); the reconstruction PSNR
(every frame re-rendered through the learned camera against the input frame); wall time (flow +
bootstrap + training + export). Writes ``OUT/layers.json``, ``OUT/layers.md`` (the table) and one
figure per run, ``OUT/<clip>-<variant>.png`` (:func:`layercam.viz.layer_bench_figure`).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from layercam.errors import LayercamError

VARIANTS = ("motion", "masks")
PREFIX = "layers_davis_"


def find_clips(data: Path, names: list[str] | None = None) -> dict[str, Path]:
    """``{clip name: folder}`` for the ``layers_davis_*`` folders of ``data`` (all, or ``names``)."""
    data = Path(data).expanduser()
    found = {p.name[len(PREFIX):]: p for p in sorted(data.glob(PREFIX + "*")) if (p / "frames").is_dir() and (p / "masks_gt").is_dir()}
    if not found:
        raise LayercamError(f"no {PREFIX}* clips (frames/ and masks_gt/) under {data}")
    if names:
        missing = [n for n in names if n not in found]
        if missing:
            raise LayercamError(f"unknown clip {missing[0]!r} (under {data}: {', '.join(found)})")
        return {n: found[n] for n in names}
    return found


def mask_ious(pred: np.ndarray, truth: np.ndarray) -> list[float]:
    """Per-frame IoU of ``pred (T, H, W)`` (> 0.5) against ``truth (T, H, W)`` (> 0.5)."""
    from layercam.metrics import iou

    return [iou(p > 0.5, g > 0.5) for p, g in zip(pred, truth)]


def read_alpha(run: Path, T: int, hw: tuple[int, int]) -> np.ndarray:
    """The run's foreground mattes ``alpha/frame_*.png`` as ``(T, H, W)`` in [0, 1]; zeros for a
    one-layer run (no foreground)."""
    from layercam.io import read_image

    files = sorted((Path(run) / "alpha").glob("frame_*.png"))
    if len(files) != T:
        return np.zeros((T, *hw), np.float32)
    return np.stack([read_image(f)[..., 0] for f in files]).astype(np.float32)


def reconstruction_psnr(model, frames: np.ndarray) -> list[float]:
    """Per-frame PSNR of the frames re-rendered through the learned camera against ``frames``."""
    from layercam.metrics import psnr
    from layercam.render import render_frame

    hw = frames.shape[1:3]
    return [psnr(np.clip(render_frame(model, t, hw, ("ldr",), blur=model.blur is not None)["ldr"], 0, 1), frames[t]) for t in range(len(frames))]


def run_layer_job(job: dict) -> dict:
    """One clip and variant, in this process: train, score, draw. Returns the result row."""
    import torch

    from layercam.config import load_config
    from layercam.io import load_clip, parse_exposures
    from layercam.io.masks import load_masks
    from layercam.checkpoint import load_run_model
    from layercam.pipelines.tasks import run_task

    torch.set_num_threads(job.get("threads", 1))
    folder, run = Path(job["folder"]), Path(job["run"])
    clip = load_clip(folder / "frames", max_frames=job.get("max_frames"), resize=job["resize"])
    truth = load_masks(folder / "masks_gt", clip)
    exposures = parse_exposures("none", clip)
    forced = ["model.layers=2"] if job.get("layers") == "2" else []
    cfg = load_config(job["preset"], forced + list(job.get("overrides", [])))
    t0 = time.perf_counter()
    # one model of the whole clip (window=0): the bench scores its checkpoint and its masks (at 854x480
    # libby's camera needs more atlas than one model holds, and hdr-video would train it as windows)
    ctx = run_task("hdr-video", clip, exposures, cfg, run, masks=truth if job["variant"] == "masks" else None, progress=False, window=0)
    total = time.perf_counter() - t0
    wall = sum((v.get("seconds") or v.get("original_seconds") or 0.0) for v in ctx.times.values())
    alpha = read_alpha(run, clip.T, (clip.H, clip.W))
    ious = mask_ious(alpha, truth)
    boot = ctx.results["bootstrap"].get("masks")
    boot_ious = mask_ious(boot, truth) if boot is not None and job["variant"] == "motion" else None
    model, _ = load_run_model(run)
    psnrs = reconstruction_psnr(model, clip.frames)
    row = {
        "clip": job["clip"], "variant": job["variant"], "frames": clip.T, "size": f"{clip.W}x{clip.H}", "preset": job["preset"],
        "layers": int(ctx.resolved.settings.model.layers), "layers_reason": ctx.resolved.reasons.get("model.layers", ""),
        "iou": round(float(np.mean(ious)), 4), "iou_min": round(float(np.min(ious)), 4),
        "bootstrap_iou": None if boot_ious is None else round(float(np.mean(boot_ious)), 4),
        "psnr": round(float(np.mean(psnrs)), 3), "wall_s": round(wall, 1), "total_s": round(total, 1),
        "steps": ctx.results["train"]["steps"], "per_frame_iou": [round(v, 4) for v in ious],
        "per_frame_bootstrap_iou": None if boot_ious is None else [round(v, 4) for v in boot_ious],
        "per_frame_psnr": [round(v, 3) for v in psnrs], "overrides": job.get("overrides", []),
        "threads": job.get("threads", 1),
    }
    draw_run(Path(job["figure"]), run, clip.frames, alpha, truth, boot, row)
    return row


def draw_run(path: Path, run: Path, frames: np.ndarray, alpha: np.ndarray, truth: np.ndarray, boot: np.ndarray | None, row: dict) -> None:
    """The run's figure (:func:`layercam.viz.layer_bench_figure`) saved as ``path``, atomically."""
    import cv2

    from layercam.io.atomic import atomic_write
    from layercam.viz import layer_bench_figure

    atlases = []
    for k in range(2):
        p = Path(run) / "atlases" / f"layer{k}.png"
        if p.exists():
            im = cv2.imread(str(p), cv2.IMREAD_UNCHANGED).astype(np.float32) / 255.0
            rgb, cov = im[..., 2::-1], im[..., 3:]
            atlases.append(rgb * cov + (1 - cov) * 0.5)  # grey where no frame looks
    title = f"{row['clip']} ({row['variant']}): alpha IoU {row['iou']:.3f}" + ("" if row["bootstrap_iou"] is None else f", bootstrap masks {row['bootstrap_iou']:.3f}") + f", PSNR {row['psnr']:.2f} dB, {row['layers']} layer(s)"
    fig = layer_bench_figure(frames, alpha, truth, atlases, boot=boot, title=title)
    atomic_write(path, lambda p: fig.savefig(p, dpi=80))


def _job_main() -> None:  # entry of the per-job subprocess
    job = json.loads(sys.argv[1])
    row = run_layer_job(job)
    from layercam.io.atomic import atomic_write

    atomic_write(Path(job["result"]), lambda p: p.write_text(json.dumps(row, indent=1)))


def run_layers_table(out: Path, data: Path, clips: list[str] | None = None, variants: tuple = VARIANTS, preset: str = "fast", resize: str = "0.33", overrides: list[str] | None = None, layers: str = "auto", max_frames: int | None = None, threads: int = 1, force: bool = False, progress: bool = True) -> list[dict]:
    """Runs (or re-uses) every clip x variant job, then writes the table. Returns the rows."""
    from layercam.io.atomic import ensure_writable_dir

    out = ensure_writable_dir(out)
    (out / "results").mkdir(exist_ok=True)
    say = print if progress else (lambda *a, **k: None)
    for v in variants:
        if v not in VARIANTS:
            raise LayercamError(f"unknown variant {v!r} (one of {', '.join(VARIANTS)})")
    rows = []
    for name, folder in find_clips(data, clips).items():
        for v in variants:
            res = out / "results" / f"{name}-{v}.json"
            job = {"clip": name, "folder": str(folder), "variant": v, "preset": preset, "resize": resize, "overrides": list(overrides or []), "layers": layers,
                   "max_frames": max_frames, "threads": threads, "run": str(out / "runs" / f"{name}-{v}"), "figure": str(out / f"{name}-{v}.png"), "result": str(res)}
            if force:
                res.unlink(missing_ok=True)
            if not res.exists():
                say(f"{name:>16} {v:>6}: running ...", flush=True)
                cmd = [sys.executable, "-c", "from layercam.bench_layers import _job_main; _job_main()", json.dumps(job)]
                p = subprocess.run(cmd, capture_output=True, text=True)
                if p.returncode != 0 or not res.exists():
                    tail = (p.stderr or p.stdout).strip().splitlines()[-1:] or ["?"]
                    raise LayercamError(f"layers bench job {name}/{v} failed: {tail[0]}")
            r = json.loads(res.read_text())
            rows.append(r)
            boot = "" if r["bootstrap_iou"] is None else f" (bootstrap {r['bootstrap_iou']:.3f})"
            say(f"{name:>16} {v:>6}: {r['layers']} layers, alpha IoU {r['iou']:.3f}{boot}, PSNR {r['psnr']:.2f} dB, {r['wall_s']:.0f} s")
    write_layers_table(out, rows)
    return rows


def write_layers_table(out: Path, rows: list[dict]) -> None:
    """``layers.json`` (every row, per-frame values included) and ``layers.md`` (the table)."""
    from layercam.io.atomic import atomic_write

    atomic_write(out / "layers.json", lambda p: p.write_text(json.dumps(rows, indent=1)))
    md = ["| clip | frames | size | masks | layers | alpha IoU (mean) | alpha IoU (worst frame) | bootstrap IoU | PSNR dB | wall s |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        boot = "" if r["bootstrap_iou"] is None else f"{r['bootstrap_iou']:.3f}"
        md.append(f"| {r['clip']} | {r['frames']} | {r['size']} | {'given' if r['variant'] == 'masks' else 'none (motion)'} | {r['layers']} | {r['iou']:.3f} | {r['iou_min']:.3f} | {boot} | {r['psnr']:.2f} | {r['wall_s']:.0f} |")
    atomic_write(out / "layers.md", lambda p: p.write_text("\n".join(md) + "\n"))
