"""``layercam bench --table finder``: the foreground finder's steps, each left out, on every DAVIS clip.

Every ``layers_davis_*`` clip under ``--data`` (its first ``MAX_FRAMES`` frames at ``--resize``, as
``--table layers`` reads it) gets the flow of each preset asked for (its ``flow`` section, as
``hdr-video`` computes it, in a temporary folder), then :func:`layercam.vision.segment.find_foreground`'s
masks with all of its optional steps (:data:`layercam.vision.segment.STEPS`), with each of them
left out, and with none (the motion masks alone), scored against the true masks: per clip the mean
IoU over its frames, its worst frame and the share of the object inside the masks; per step set the
set's mean and its worst clip. No training: this measures the masks a two-layer run starts from and
what each step adds to them (``--table layers`` scores the trained alpha). A finished clip leaves
``OUT/results/finder-<clip>-<preset>.json`` and is not run again (``--force`` redoes it). Writes
``OUT/finder.json`` and ``OUT/finder.md``.
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np


def step_sets() -> dict[str, tuple]:
    """``{name: steps}``: all of :data:`~layercam.vision.segment.STEPS`, each left out, none."""
    from layercam.vision.segment import STEPS

    sets = {"all": STEPS}
    plated = ("colour", "texture")  # the steps that read the clean plate: without it, neither
    for s in STEPS:
        sets[f"without {s}" + (" (and colour, texture)" if s == "background" else "")] = tuple(x
            for x in STEPS if x != s and not (s == "background" and x in plated))
    sets["motion masks alone"] = ()
    return sets


def clip_flows(clip, flow_cfg) -> dict:
    """The flow a run computes for ``clip`` (``flow_cfg``: its ``flow`` section), in a temporary
    folder, at the frames' size: ``{fw, bw, fw_ok, bw_ok}`` arrays."""
    from layercam.vision import flow_store
    from layercam.vision.flow_store import at_frame_size

    keys = ("fw", "bw", "fw_ok", "bw_ok")
    with tempfile.TemporaryDirectory(prefix="layercam-finder-") as work:
        flow_store.compute(clip.frames, Path(work), flow_cfg)
        fl = at_frame_size(flow_store.load(Path(work)), (clip.H, clip.W), keys)
        return {k: np.array(fl[k][:]) for k in keys}  # read before the folder goes


def finder_inputs(folder: Path, preset: str = "fast", resize: str = "0.33", max_frames: int | None = None,
                  overrides: list[str] | None = None) -> tuple:
    """What the finder reads for one ``layers_davis_*`` clip ``folder`` at the bench's setting
    (defaults: ``--table layers``'s): ``(clip, truth masks (T, H, W), config, flows, flow seconds)``."""
    from layercam.bench.layers import MAX_FRAMES
    from layercam.core.presets import load_config
    from layercam.io import load_clip
    from layercam.io.masks import load_masks

    clip = load_clip(Path(folder) / "frames", max_frames=max_frames or MAX_FRAMES, resize=resize)
    truth = load_masks(Path(folder) / "masks_gt", clip)
    cfg = load_config(preset, list(overrides or []))
    t0 = time.perf_counter()
    flows = clip_flows(clip, cfg.flow)
    return clip, truth, cfg, flows, time.perf_counter() - t0


def run_finder_clip(name: str, folder: Path, preset: str, resize: str, max_frames: int,
                    overrides: list[str] | None = None) -> dict:
    """One clip at one preset's flow, in this process: ``{clip, preset, frames, size, flow_s,
    sets: {name: {iou, iou_min, inside, seconds}}}``."""
    from layercam.bench.layers import inside_share, mask_ious
    from layercam.vision.segment import find_foreground

    clip, truth, cfg, flows, flow_s = finder_inputs(folder, preset, resize, max_frames, overrides)
    sets = {}
    for label, steps in step_sets().items():
        t0 = time.perf_counter()
        masks, _ = find_foreground(clip.frames, flows, cfg.segment, steps=steps)
        ious = mask_ious(masks, truth)
        sets[label] = {"iou": round(float(np.mean(ious)), 4), "iou_min": round(float(np.min(ious)), 4),
                       "inside": round(inside_share(masks, truth), 4), "seconds": round(time.perf_counter() - t0, 2)}
    return {"clip": name, "preset": preset, "frames": clip.T, "size": f"{clip.W}x{clip.H}",
            "flow_s": round(flow_s, 1), "sets": sets}


def summarise(rows: list[dict]) -> list[dict]:
    """Per split (:func:`layercam.bench.layers.split_of`, never mixed), preset and step set: the
    split's mean IoU, its worst clip and the mean share inside."""
    from layercam.bench.layers import SPLITS, split_of

    out = []
    keys = dict.fromkeys((split_of(r["clip"]), r["preset"]) for r in rows)
    for split, preset in sorted(keys, key=lambda k: SPLITS.index(k[0])):
        mine = [r for r in rows if r["preset"] == preset and split_of(r["clip"]) == split]
        for label in step_sets():
            vals = [(r["sets"][label]["iou"], r["clip"], r["sets"][label]["inside"]) for r in mine
                    if label in r["sets"]]
            if vals:
                worst = min(vals)
                out.append({"split": split, "preset": preset, "steps": label, "clips": len(vals),
                            "mean": round(float(np.mean([v[0] for v in vals])), 4),
                            "worst": worst[0], "worst_clip": worst[1],
                            "inside": round(float(np.mean([v[2] for v in vals])), 4)})
    return out


def finder_markdown(rows: list[dict], summary: list[dict], command: str) -> str:
    """``finder.md``: per split (validation first, never mixed) the split's mean and worst clip per
    step set, then every clip."""
    from layercam.bench.layers import split_of, split_title

    labels = list(step_sets())
    lines = ["# The foreground finder's steps, each left out (masks against the true masks, no "
             "training)", "", f"Regenerate: `{command}`"]
    for split in dict.fromkeys(s["split"] for s in summary):
        lines += ["", split_title(split), "",
                  "| preset | steps | clips | mean IoU | worst clip | object inside (mean) |",
                  "|---|---|---|---|---|---|"]
        lines += [f"| `{s['preset']}` | {s['steps']} | {s['clips']} | {s['mean']:.3f} | "
                  f"{s['worst_clip']} {s['worst']:.3f} | {s['inside']:.3f} |"
                  for s in summary if s["split"] == split]
        lines += ["", "Per clip, mean IoU (worst frame):", "",
                  "| clip | preset | " + " | ".join(labels) + " |", "|---|---|" + "---|" * len(labels)]
        lines += [f"| {r['clip']} | `{r['preset']}` | "
                  + " | ".join(f"{r['sets'][k]['iou']:.3f} ({r['sets'][k]['iou_min']:.2f})"
                               if k in r["sets"] else "" for k in labels) + " |"
                  for r in rows if split_of(r["clip"]) == split]
    return "\n".join(lines) + "\n"


def run_finder_table(out: Path, data: Path, clips: list[str] | None = None,
                     presets: tuple = ("fast", "balanced"), resize: str = "0.33",
                     max_frames: int | None = None,
                     overrides: list[str] | None = None, force: bool = False, progress: bool = True,
                     command: str = "layercam bench --table finder",
                     split: str = "validation") -> list[dict]:
    """Runs (or re-uses) every preset x clip (``clips``, else those of ``split``), then writes
    ``finder.json`` and ``finder.md`` (``command``: the line that regenerates it, as typed).
    Returns the rows."""
    from layercam.bench.layers import MAX_FRAMES, find_clips
    from layercam.core.progress import bar
    from layercam.io.atomic import atomic_write

    out = Path(out)
    found = find_clips(data, clips, split)
    (out / "results").mkdir(parents=True, exist_ok=True)
    rows = []
    jobs = [(p, c) for p in presets for c in found]
    for preset, name in bar(jobs, desc="finder", unit="clip", enabled=progress):
        res = out / "results" / f"finder-{name}-{preset}.json"
        if res.exists() and not force:
            rows.append(json.loads(res.read_text()))
            continue
        row = run_finder_clip(name, found[name], preset, resize, max_frames or MAX_FRAMES, overrides)
        atomic_write(res, lambda p: p.write_text(json.dumps(row, indent=1)))
        rows.append(row)
    summary = summarise(rows)
    atomic_write(out / "finder.json", lambda p: p.write_text(json.dumps({"summary": summary, "rows": rows}, indent=1)))
    atomic_write(out / "finder.md", lambda p: p.write_text(finder_markdown(rows, summary, command)))
    return rows
