"""``layercam bench --table layers``: the layered scene on real footage, scored against ground truth.

Every ``layers_davis_*`` clip under ``--data`` (DAVIS clips with per-frame foreground masks in
``masks_gt/``) of the split asked for (:data:`VALIDATION`: DAVIS 2016's validation sequences, judged
on and never fitted on; every other clip is of its training split, where anything learned or tuned
is fitted) runs as ``layercam hdr-video FRAMES --exposures none --layers 2 --resize R``, on its
first ``MAX_FRAMES`` frames (one protocol for every clip), at each preset asked for: with its masks
given (``--masks``, variant "masks") and without (variant "motion": the foreground is found by
:mod:`layercam.vision.segment`). Each run is its own process (one torch thread unless told otherwise) and
keeps its run folder under ``OUT/runs/``; a finished job leaves
``OUT/results/<clip>-<variant>-<preset>.json`` and is not run again (delete the file to re-measure),
so an interrupted benchmark resumes.

Per run: the layers; the foreground alpha's IoU against the true masks (alpha > 0.5, per frame, then
the mean) and its worst frame; the share of the object inside alpha (true mask pixels under alpha >
0.5, over the clip), both at the clip's working size (the masks resampled as the frames are) and, as
DAVIS scores, at the masks' own size (the mattes upsampled bilinearly); the bootstrap masks' IoU and
the finder's verdict (variant "motion"); the
reconstruction PSNR (every frame re-rendered through the learned camera against the input frame);
wall time (flow + bootstrap + training + export). Writes ``OUT/layers.json``, ``OUT/layers.md`` (per
split its own table, and per preset and variant the split's mean and worst clip: the two splits are
never mixed) and one figure per run,
``OUT/<clip>-<variant>-<preset>.png`` (:func:`layercam.bench.viz.layer_bench_figure`).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from layercam.core.errors import LayercamError

VARIANTS = ("motion", "masks")
PREFIX = "layers_davis_"
MAX_FRAMES = 24  # every clip's first 24 frames (the shortest DAVIS clip in the set has 30; libby has 49)
# DAVIS 2016's validation sequences (Perazzi et al. 2016): the clips a change is judged on, never fitted on
VALIDATION = frozenset((
    "blackswan", "bmx-trees", "breakdance", "camel", "car-roundabout", "car-shadow", "cows",
    "dance-twirl", "dog", "drift-chicane", "drift-straight", "goat", "horsejump-high", "kite-surf",
    "libby", "motocross-jump", "paragliding-launch", "parkour", "scooter-black", "soapbox"))
SPLITS = ("validation", "training", "all")


def split_of(clip: str) -> str:
    """``"validation"`` for a DAVIS 2016 validation sequence, else ``"training"``."""
    return "validation" if clip in VALIDATION else "training"


def split_title(split: str) -> str:
    """A split's heading in the benches' tables: its name and what it is for."""
    return f"## The {split} split" + (" (judged on, never fitted on)" if split == "validation"
                                     else " (where anything learned or tuned is fitted)")


def find_clips(data: Path, names: list[str] | None = None, split: str = "all") -> dict[str, Path]:
    """``{clip name: folder}`` for the ``layers_davis_*`` folders of ``data``: ``names``, else
    every clip of ``split`` (:data:`SPLITS`)."""
    if split not in SPLITS:
        raise LayercamError(f"unknown split {split!r} (one of {', '.join(SPLITS)})")
    data = Path(data).expanduser()
    found = {p.name[len(PREFIX):]: p for p in sorted(data.glob(PREFIX + "*"))
             if (p / "frames").is_dir() and (p / "masks_gt").is_dir()}
    if not found:
        raise LayercamError(f"no {PREFIX}* clips (frames/ and masks_gt/) under {data}")
    if not names and split != "all":
        found = {k: v for k, v in found.items() if split_of(k) == split}
        if not found:
            raise LayercamError(f"no clip of the {split} split under {data}")
    if names:
        missing = [n for n in names if n not in found]
        if missing:
            raise LayercamError(f"unknown clip {missing[0]!r} (under {data}: {', '.join(found)})")
        return {n: found[n] for n in names}
    return found


def mask_ious(pred: np.ndarray, truth: np.ndarray) -> list[float]:
    """Per-frame IoU of ``pred (T, H, W)`` (> 0.5) against ``truth (T, H, W)`` (> 0.5)."""
    from layercam.core.metrics import iou

    return [iou(p > 0.5, g > 0.5) for p, g in zip(pred, truth)]


def inside_share(pred: np.ndarray, truth: np.ndarray) -> float:
    """The share of the object inside ``pred``: true pixels (``truth > 0.5``) where ``pred > 0.5``,
    over every frame (1 when the truth holds none)."""
    g = np.asarray(truth) > 0.5
    return float(np.count_nonzero((np.asarray(pred) > 0.5) & g) / max(np.count_nonzero(g), 1)) if g.any() else 1.0


def source_scores(alpha: np.ndarray, masks: Path, clip) -> dict:
    """``alpha (T, H, W)`` scored as DAVIS scores, at the true masks' own resolution: each matte
    upsampled bilinearly to the masks' size and > 0.5, against the masks there. Returns
    ``{"iou_source", "iou_min_source", "inside_source", "source_size"}``."""
    import cv2

    from layercam.io.masks import load_masks

    truth = load_masks(masks, clip, own_size=True)
    hw = truth.shape[1:3]
    up = [cv2.resize(np.asarray(a, np.float32), (hw[1], hw[0]), interpolation=cv2.INTER_LINEAR) for a in alpha]
    ious = mask_ious(up, truth)
    hit = sum(int(np.count_nonzero((u > 0.5) & (g > 0.5))) for u, g in zip(up, truth))
    total = int(np.count_nonzero(np.asarray(truth) > 0.5))
    return {"iou_source": round(float(np.mean(ious)), 4), "iou_min_source": round(float(np.min(ious)), 4),
            "inside_source": round(hit / total, 4) if total else 1.0, "source_size": f"{hw[1]}x{hw[0]}"}


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
    from layercam.core.metrics import psnr
    from layercam.scene.render import render_frame

    hw = frames.shape[1:3]
    return [psnr(np.clip(render_frame(model, t, hw, ("ldr",), blur=model.blur is not None)["ldr"],
                         0, 1), frames[t]) for t in range(len(frames))]


def run_layer_job(job: dict) -> dict:
    """One clip and variant, in this process: train, score, draw. Returns the result row."""
    import torch

    from layercam.core.presets import load_config
    from layercam.io import load_clip, parse_exposures
    from layercam.io.masks import load_masks
    from layercam.engine.checkpoint import load_run_model
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
    ctx = run_task("hdr-video", clip, exposures, cfg, run,
                   masks=truth if job["variant"] == "masks" else None, progress=False, window=0)
    total = time.perf_counter() - t0
    wall = sum((v.get("seconds") or v.get("original_seconds") or 0.0) for v in ctx.times.values())
    alpha = read_alpha(run, clip.T, (clip.H, clip.W))
    ious = mask_ious(alpha, truth)
    boot = ctx.results["bootstrap"].masks
    boot_ious = mask_ious(boot, truth) if boot is not None and job["variant"] == "motion" else None
    verdict = ctx.results["bootstrap"].verdict if job["variant"] == "motion" else {}
    model, _ = load_run_model(run)
    psnrs = reconstruction_psnr(model, clip.frames)
    row = {
        "clip": job["clip"], "variant": job["variant"], "frames": clip.T,
        "size": f"{clip.W}x{clip.H}", "preset": job["preset"],
        "layers": int(ctx.resolved.settings.model.layers),
        "layers_reason": ctx.resolved.reasons.get("model.layers", ""),
        "iou": round(float(np.mean(ious)), 4), "iou_min": round(float(np.min(ious)), 4),
        "inside": round(inside_share(alpha, truth), 4),
        "found": verdict.get("found"), "verdict": verdict.get("reason", ""),
        "bootstrap_iou": None if boot_ious is None else round(float(np.mean(boot_ious)), 4),
        "psnr": round(float(np.mean(psnrs)), 3), "wall_s": round(wall, 1), "total_s": round(total, 1),
        "steps": ctx.results["train"].steps, "per_frame_iou": [round(v, 4) for v in ious],
        "per_frame_bootstrap_iou": None if boot_ious is None else [round(v, 4) for v in boot_ious],
        "per_frame_psnr": [round(v, 3) for v in psnrs], "overrides": job.get("overrides", []),
        "threads": job.get("threads", 1), **source_scores(alpha, folder / "masks_gt", clip),
    }
    draw_run(Path(job["figure"]), run, clip.frames, alpha, truth, boot, row)
    return row


def draw_run(path: Path, run: Path, frames: np.ndarray, alpha: np.ndarray, truth: np.ndarray,
             boot: np.ndarray | None, row: dict) -> None:
    """The run's figure (:func:`layercam.bench.viz.layer_bench_figure`) saved as ``path``, atomically."""
    import cv2

    from layercam.io.atomic import atomic_write
    from layercam.bench.viz import layer_bench_figure

    atlases = []
    for k in range(2):
        p = Path(run) / "atlases" / f"layer{k}.png"
        if p.exists():
            im = cv2.imread(str(p), cv2.IMREAD_UNCHANGED).astype(np.float32) / 255.0
            rgb, cov = im[..., 2::-1], im[..., 3:]
            atlases.append(rgb * cov + (1 - cov) * 0.5)  # grey where no frame looks
    title = (f"{row['clip']} ({row['variant']}, {row['preset']}): alpha IoU {row['iou']:.3f}"
             + ("" if row["bootstrap_iou"] is None
                else f", bootstrap masks {row['bootstrap_iou']:.3f}")
             + f", PSNR {row['psnr']:.2f} dB, {row['layers']} layer(s)")
    fig = layer_bench_figure(frames, alpha, truth, atlases, boot=boot, title=title)
    atomic_write(path, lambda p: fig.savefig(p, dpi=80))


def _job_main() -> None:  # entry of the per-job subprocess
    job = json.loads(sys.argv[1])
    row = run_layer_job(job)
    from layercam.io.atomic import atomic_write

    atomic_write(Path(job["result"]), lambda p: p.write_text(json.dumps(row, indent=1)))


def run_layers_table(out: Path, data: Path, clips: list[str] | None = None,
                     variants: tuple = VARIANTS, presets: tuple = ("fast", "balanced"),
                     resize: str = "0.33", overrides: list[str] | None = None, layers: str = "2",
                     max_frames: int | None = MAX_FRAMES, threads: int = 1, force: bool = False,
                     progress: bool = True, split: str = "validation") -> list[dict]:
    """Runs (or re-uses) every preset x clip (``clips``, else those of ``split``) x variant job,
    then writes the table. Returns the rows."""
    from layercam.io.atomic import ensure_writable_dir

    out = ensure_writable_dir(out)
    (out / "results").mkdir(exist_ok=True)
    say = print if progress else (lambda *a, **k: None)
    for v in variants:
        if v not in VARIANTS:
            raise LayercamError(f"unknown variant {v!r} (one of {', '.join(VARIANTS)})")
    if isinstance(presets, str):
        presets = (presets,)
    rows = []
    for preset, (name,
                 folder), v in ((p, c, v) for p in presets
                                for c in find_clips(data, clips, split).items() for v in variants):
        tag = f"{name}-{v}-{preset}"
        res = out / "results" / f"{tag}.json"
        job = {"clip": name, "folder": str(folder), "variant": v, "preset": preset,
               "resize": resize, "overrides": list(overrides or []), "layers": layers,
               "max_frames": max_frames, "threads": threads, "run": str(out / "runs" / tag),
               "figure": str(out / f"{tag}.png"), "result": str(res)}
        if force:
            res.unlink(missing_ok=True)
        if not res.exists():
            say(f"{name:>18} {v:>6} {preset:>8}: running ...", flush=True)
            cmd = [sys.executable, "-c", "from layercam.bench.layers import _job_main; _job_main()", json.dumps(job)]
            p = subprocess.run(cmd, capture_output=True, text=True)
            if p.returncode != 0 or not res.exists():
                tail = (p.stderr or p.stdout).strip().splitlines()[-1:] or ["?"]
                raise LayercamError(f"layers bench job {name}/{v} failed: {tail[0]}")
        r = json.loads(res.read_text())
        rows.append(r)
        boot = "" if r["bootstrap_iou"] is None else f" (bootstrap {r['bootstrap_iou']:.3f})"
        say(f"{name:>18} {v:>6} {preset:>8}: {r['layers']} layers, alpha IoU {r['iou']:.3f}, "
            f"inside {r.get('inside', float('nan')):.3f}{boot}, PSNR {r['psnr']:.2f} dB, "
            f"{r['wall_s']:.0f} s")
    write_layers_table(out, rows)
    return rows


def summaries(rows: list[dict]) -> list[dict]:
    """Per split, preset and variant: the split's mean alpha IoU, mean share inside, and its worst
    clip (and the bootstrap masks' mean, where the rows have it)."""
    out = []
    key_of = lambda r: (split_of(r["clip"]), r.get("preset", ""), r["variant"])  # noqa: E731
    for key in sorted(dict.fromkeys(key_of(r) for r in rows), key=lambda k: SPLITS.index(k[0])):
        rs = [r for r in rows if key_of(r) == key]
        worst = min(rs, key=lambda r: r["iou"])
        inside = [r["inside"] for r in rs if r.get("inside") is not None]
        boot = [r["bootstrap_iou"] for r in rs if r.get("bootstrap_iou") is not None]
        out.append({"split": key[0], "preset": key[1], "variant": key[2], "clips": len(rs),
                    "bootstrap_mean": round(float(np.mean(boot)), 4) if len(boot) == len(rs) else None,
                    "iou_mean": round(float(np.mean([r["iou"] for r in rs])), 4),
                    "inside_mean": round(float(np.mean(inside)), 4) if inside else None,
                    "inside_min": round(float(np.min(inside)), 4) if inside else None,
                    "worst_clip": worst["clip"], "worst_iou": worst["iou"]})
        src = [r for r in rs if r.get("iou_source") is not None]
        if len(src) == len(rs):  # scored at the masks' own size too
            out[-1].update({"iou_source_mean": round(float(np.mean([r["iou_source"] for r in src])), 4),
                            "inside_source_min": round(float(np.min([r["inside_source"] for r in src])), 4),
                            "worst_iou_source": round(float(np.min([r["iou_source"] for r in src])), 4)})
    return out


def write_layers_table(out: Path, rows: list[dict]) -> None:
    """``layers.json`` (every row, per-frame values included, and the summaries) and ``layers.md``
    (per split, validation first: its table, then one line per preset and variant: the split's
    mean, its bootstrap masks' mean and its worst clip)."""
    from layercam.io.atomic import atomic_write

    sums = summaries(rows)
    atomic_write(out / "layers.json",
                 lambda p: p.write_text(json.dumps({"rows": rows, "summary": sums}, indent=1)))
    md = []
    for split in [s for s in SPLITS if any(split_of(r["clip"]) == s for r in rows)]:
        md += [split_title(split), "",
               "| clip | preset | frames | size | masks | layers | alpha IoU (mean) | alpha IoU "
               "(worst frame) | object inside alpha | at the masks' own size: IoU / inside | "
               "bootstrap IoU | found | PSNR dB | wall s |",
               "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in (r for r in rows if split_of(r["clip"]) == split):
            boot = "" if r["bootstrap_iou"] is None else f"{r['bootstrap_iou']:.3f}"
            inside = "" if r.get("inside") is None else f"{r['inside']:.3f}"
            found = "" if r.get("found") is None else ("yes" if r["found"] else "no")
            src = ("" if r.get("iou_source") is None
                   else f"{r['iou_source']:.3f} / {r['inside_source']:.3f} ({r['source_size']})")
            md.append(f"| {r['clip']} | {r.get('preset', '')} | {r['frames']} | {r['size']} | "
                      f"{'given' if r['variant'] == 'masks' else 'none (motion)'} | {r['layers']} | "
                      f"{r['iou']:.3f} | {r['iou_min']:.3f} | {inside} | {src} | {boot} | {found} | "
                      f"{r['psnr']:.2f} | {r['wall_s']:.0f} |")
        md += ["",
               "| preset | masks | clips | mean alpha IoU | its bootstrap masks | mean share inside | "
               "least share inside | worst clip | at the masks' own size: mean IoU / least inside / "
               "worst clip's IoU |", "|---|---|---|---|---|---|---|---|---|"]
        for sm in (sm for sm in sums if sm["split"] == split):
            ins = "" if sm["inside_mean"] is None else f"{sm['inside_mean']:.3f}"
            least = "" if sm["inside_min"] is None else f"{sm['inside_min']:.3f}"
            boot = "" if sm.get("bootstrap_mean") is None else f"{sm['bootstrap_mean']:.3f}"
            src = (f"{sm['iou_source_mean']:.3f} / {sm['inside_source_min']:.3f} / "
                   f"{sm['worst_iou_source']:.3f}" if "iou_source_mean" in sm else "")
            md.append(f"| {sm['preset']} | {'given' if sm['variant'] == 'masks' else 'none (motion)'} "
                      f"| {sm['clips']} | {sm['iou_mean']:.3f} | {boot} | {ins} | {least} | "
                      f"{sm['worst_clip']} {sm['worst_iou']:.3f} | {src} |")
        md.append("")
    atomic_write(out / "layers.md", lambda p: p.write_text("\n".join(md)))
