"""One job of the real suite, run in its own process (``python -m layercam.bench.realsuite.jobs JOB``) so
that its peak memory (``ru_maxrss``) and wall time are its own.

Kinds: ``prepare`` (render a composite's frames, compute the ground truth or the reference),
``classical`` (OpenCV's merges, scored) and ``layercam`` (the command line a user would type, run
as ``python -m layercam`` by :func:`layercam.bench.command.run_layercam`, then scored). Each writes
``result.json`` into its
folder: ``{"rows": [table rows], ...}``; a row that failed carries ``"failed"``.
"""

from __future__ import annotations

import json
import os
import resource
import sys
import time
from pathlib import Path

import numpy as np

from layercam.bench.realsuite.cases import (CASES, case_inputs, load_inputs, load_truth,
                                            prepare_composite, prepare_shake, read_prediction)

__all__ = ["run_job", "analysis_summary", "code_version"]


def code_version() -> str:
    """The commit of the layercam code that runs (``+dirty`` with uncommitted changes), or ``?``."""
    import subprocess

    here = Path(__file__).resolve().parents[3]
    try:
        head = subprocess.run(["git", "-C", str(here), "rev-parse", "--short", "HEAD"],
                              capture_output=True, text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(here), "status", "--porcelain", "--", "layercam",
                                "pipelines", "configs"], capture_output=True, text=True,
                               timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "?"
    return (head or "?") + ("+dirty" if dirty else "")


def _peak_mb() -> float:
    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)


def _load() -> float:
    return round(os.getloadavg()[0], 2)


def _round(d: dict) -> dict:
    return {k: (round(float(v), 4) if isinstance(v, (float, np.floating)) else v) for k, v in d.items()}


def analysis_summary(analysis: dict) -> dict:
    """What the analysis chose (``report.json["analysis"]``) in a line, and its reasons."""
    a = analysis or {}
    blur = a.get("blur", "?")
    choice = f"{a.get('layers', '?')} layer(s), blur {blur}" + (f" (s {a.get('max_offset'):g})"
        if blur not in ("off", "?") and a.get("max_offset") is not None else "")
    choice += f", tone {a.get('tone_mapper', '?')}, flow loss {'on' if a.get('flow_loss') else 'off'}"
    reasons = a.get("reasons") or {}
    return {"choice": choice,
            "reasons": {k: reasons[k] for k in ("layers", "blur", "flow_loss", "tone_mapper")
                        if k in reasons}}


def _scores(case, pred: np.ndarray, truth: dict | None, frames: np.ndarray) -> dict:
    from layercam.bench.realsuite.measures import score_hdr

    if truth is None:
        return {}
    return score_hdr(pred, truth["hdr"], truth["unseen"], truth.get("fg"))


def _video_flicker(pred: np.ndarray, frames: np.ndarray, case_dir: Path) -> dict:
    """Flicker of the tonemapped video (one tonemap for the whole clip, as preview.mp4) on the
    clip's static pixels, and their share; the registration and the masks are the input's, cached
    in ``case_dir/static.npz`` so that every method is measured on the same pixels."""
    from layercam.bench.realsuite.measures import flicker
    from layercam.scene.render import tonemap_display

    hom, static = static_pixels(frames, case_dir)
    _, stats = tonemap_display(pred)
    disp = np.stack([tonemap_display(p, stats)[0] for p in pred])
    return {"flicker": flicker(disp, hom, static), "static_share": float(static.mean())}


def static_pixels(frames: np.ndarray, case_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """The clip's registration and static masks (:mod:`layercam.bench.realsuite.measures`), cached."""
    from layercam.bench.realsuite.measures import registration, static_masks

    cache = Path(case_dir) / "static.npz"
    if cache.exists():
        z = np.load(cache)
        if z["static"].shape[1:] == frames.shape[1:3] and len(z["hom"]) == len(frames) - 1:
            return z["hom"], z["static"]
    hom = registration(frames)
    static = static_masks(frames, hom)
    np.savez_compressed(cache, hom=hom, static=static)
    return hom, static


def _context(job: dict):
    case = CASES[job["case"]]
    case_dir = Path(job["case_dir"])
    ci = case_inputs(case, case_dir, Path(job["data"]), job.get("quick", False), job.get("max_frames"))
    return case, case_dir, ci


def job_prepare(job: dict) -> dict:
    case, case_dir, ci = _context(job)
    if case.group == "composite":
        prepare_composite(case, case_dir, Path(job["data"]), Path(job["shared_dir"]), job.get("quick", False))
    if case.params.get("shake"):
        prepare_shake(case, case_dir, Path(job["data"]), job.get("quick", False))
    frames, times, _ = load_inputs(case, ci)
    truth = load_truth(case, case_dir, Path(job["data"]), frames, times)
    unseen = (float(truth["unseen"].mean()) if truth is not None and "unseen" in truth
              else float(np.mean([_unseen_pair(frames, t) for t in range(len(frames) - 1)])))
    return {"rows": [], "clipped_share": unseen, "frames": int(len(frames)),
            "size": [int(frames.shape[2]), int(frames.shape[1])]}


def _unseen_pair(frames: np.ndarray, t: int) -> float:
    from layercam.bench.realsuite.measures import unseen_mask

    return float(unseen_mask(frames[t : t + 2]).mean())


DEBLUR_METHODS = {
    "input": "the blurry input itself: the floor",
    "unsharp": "unsharp masking, sigma 1.5 px, amount 1 (layercam.bench.baselines.unsharp_mask)",
    "lucky": "flow-aligned lucky regions from 2 neighbours either side (layercam.bench.baselines.lucky_regions)",
}


def _classical_deblur(case, case_dir: Path, frames: np.ndarray, truth: dict, out_dir: Path) -> dict:
    from layercam.bench.realsuite.classical import deblur_baselines
    from layercam.bench.realsuite.measures import score_deblur

    res = deblur_baselines(frames)
    floor = score_deblur(frames, truth["sharp"])["psnr_frames"]
    rows = []
    for name, r in res.items():
        if name != "input":
            np.save(out_dir / f"{name}.npy", r["ldr"].astype(np.float32))
        rows.append(_round({"method": name, "preset": "", "wall_s": round(r["seconds"], 2),
                            "note": DEBLUR_METHODS[name],
                            **score_deblur(r["ldr"], truth["sharp"], floor)}))
    return {"rows": rows}


def job_classical(job: dict) -> dict:
    from layercam.bench.realsuite.classical import bracket_merges, video_merge

    case, case_dir, ci = _context(job)
    frames, times, _ = load_inputs(case, ci)
    truth = load_truth(case, case_dir, Path(job["data"]), frames, times)
    out_dir = Path(job["dir"])
    if case.group == "deblur":
        return _classical_deblur(case, case_dir, frames, truth, out_dir)
    rows = []
    if case.task == "fuse-stack":
        res = bracket_merges(frames, times)
        np.save(out_dir / "mertens.npy", res.pop("mertens")["ldr"])
        methods = {"debevec": "OpenCV CalibrateDebevec + MergeDebevec, same shots and times, "
                              "unaligned",
                   "robertson": "OpenCV CalibrateRobertson + MergeRobertson, same shots and times, "
                                "unaligned"}
    else:
        res = {"flow+debevec": video_merge(frames, times)}
        methods = {"flow+debevec": "OpenCV Debevec of each frame with its DIS-aligned neighbour "
                                   "(layercam.bench.baselines.debevec_video)"}
    for name, r in res.items():
        np.save(out_dir / f"{name}.npy", r["hdr"].astype(np.float32))
        row = {"method": name, "preset": "", "wall_s": round(r["seconds"], 2), "note": methods[name]}
        if case.name == "frobisher" and name == "robertson":
            row["note"] = "this merge is the reference itself (the bracket has only these 3 shots): not scored"
        else:
            row.update(_scores(case, r["hdr"], truth, frames))
        if case.group == "video":
            row.update(_video_flicker(r["hdr"], frames, case_dir))
        rows.append(_round(row))
    return {"rows": rows}


def job_layercam(job: dict) -> dict:
    """Run ``layercam <task> <inputs> --preset P --out DIR`` (in a process of its own, whose wall
    time and peak memory the row keeps), then score it."""
    from layercam.bench.command import run_layercam

    case, case_dir, ci = _context(job)
    run_dir = Path(job["dir"]) / "run"
    argv = [case.task, *ci["argv"], "--preset", job["preset"], "--out", str(run_dir), "--quiet"]
    for s in job.get("overrides", []):
        argv += ["--set", s]
    load0 = _load()
    ran = run_layercam(argv, int(job.get("threads", 1)), run_dir / "report.json")
    rc = ran["returncode"]
    row = {"method": "layercam", "preset": job["preset"], "wall_s": round(ran["wall_s"], 2),
           "peak_mem_mb": ran["peak_mem_mb"], "load": f"{load0:.1f}-{_load():.1f}",
           "command": "layercam " + " ".join(argv)}
    if rc != 0:
        return {"rows": [{**row, "failed": f"exit {rc}"}]}
    report = json.loads((run_dir / "report.json").read_text())
    frames, times, _ = load_inputs(case, ci)
    pred = read_prediction(case, run_dir, len(frames))
    truth = load_truth(case, case_dir, Path(job["data"]), frames, times)
    if case.group == "deblur":
        from layercam.bench.realsuite.measures import score_deblur

        row.update(score_deblur(pred, truth["sharp"], score_deblur(frames, truth["sharp"])["psnr_frames"]))
        share = ((report.get("export") or {}).get("trust") or {}).get("kept_share")
        if share:  # pipelines/view.py: where the sharp render is kept, the input elsewhere
            row.update(kept_share=float(np.mean(share)),
                       note=f"sharp render kept on {np.mean(share):.0%} of the pixels (frames "
                            f"{min(share):.0%}-{max(share):.0%})")
    else:
        row.update(_scores(case, pred, truth, frames))
    if case.group == "video":
        row.update(_video_flicker(pred, frames, case_dir))
    tr = report.get("train", {})
    row.update(steps=tr.get("steps"), train_s=tr.get("seconds_this_session"),
               analysis=analysis_summary(report.get("analysis")))
    return {"rows": [_round(row)]}


JOBS = {"prepare": job_prepare, "classical": job_classical, "layercam": job_layercam}


def run_job(job: dict) -> dict:
    """Run ``job`` here; returns its result (also written to ``job["dir"]/result.json``)."""
    from layercam.io.atomic import atomic_write

    out = Path(job["dir"])
    out.mkdir(parents=True, exist_ok=True)
    load0 = _load()
    t0 = time.perf_counter()
    res = JOBS[job["kind"]](job)
    res.update(job={k: v for k, v in job.items() if k not in ("data",)},
               seconds=round(time.perf_counter() - t0, 2), peak_mem_mb=_peak_mb(), load_start=load0,
               load_end=_load(), code=code_version())
    for r in res["rows"]:
        r.setdefault("peak_mem_mb", res["peak_mem_mb"])
        r.setdefault("load", f"{load0:.1f}-{res['load_end']:.1f}")
    atomic_write(out / "result.json", lambda p: p.write_text(json.dumps(res, indent=1, default=_json_default)))
    return res


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


if __name__ == "__main__":  # pragma: no cover - run by the suite in a subprocess
    run_job(json.loads(sys.argv[1]))
