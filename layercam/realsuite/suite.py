"""``layercam bench --suite real``: every case, each job in its own process, resumable.

Jobs per case: ``prepare`` (composite frames, ground truth or reference), ``classical`` (OpenCV),
then one ``layercam`` job per preset. A job whose ``result.json`` exists (and did not fail) is
skipped on a rerun unless ``force``; after every job the table (``real_suite.csv``/``.md``) and the
case's figure (``cases/<case>/figure.png``) are written again from what is on disk, so a long run
can be read while it goes. The classical jobs of all cases run first, then the presets in dial
order (all cases at ``fast`` before any at ``balanced``).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

from layercam.errors import LayercamError
from layercam.realsuite.cases import CASES

__all__ = ["run_real_suite", "resolve_data", "QUICK_OVERRIDES"]

QUICK_OVERRIDES = ["train.steps=8", "train.bootstrap_steps=2", "train.batch=1024"]


def resolve_data(data: str | os.PathLike | None) -> Path:
    """The shared captures: ``data``, else ``$LAYERCAM_DATA``, else ``../shared/data``."""
    p = Path(data or os.environ.get("LAYERCAM_DATA") or "../shared/data").expanduser()
    if not p.is_dir():
        raise LayercamError(f"shared captures not found at {p} (give --data DIR or set LAYERCAM_DATA)")
    return p.resolve()


def _done(job_dir: Path) -> bool:
    res = job_dir / "result.json"
    if not res.exists():
        return False
    try:
        rows = json.loads(res.read_text()).get("rows", [])
    except json.JSONDecodeError:
        return False
    return not any(r.get("failed") for r in rows)


def _spawn(job: dict, threads: int) -> None:
    """Run one job in its own process; a crash becomes a failed row (the suite goes on)."""
    from layercam.io.atomic import atomic_write

    d = Path(job["dir"])
    d.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "OMP_NUM_THREADS": str(threads)}
    with open(d / "log.txt", "w") as log:
        p = subprocess.run([sys.executable, "-m", "layercam.realsuite.jobs", json.dumps(job)], stdout=log, stderr=subprocess.STDOUT, env=env)
    if p.returncode != 0:
        lines = (d / "log.txt").read_text(errors="replace").strip().splitlines() or ["?"]
        row = {"method": job["kind"] if job["kind"] != "layercam" else "layercam", "preset": job.get("preset", ""), "failed": lines[-1][:200]}
        atomic_write(d / "result.json", lambda q: q.write_text(json.dumps({"rows": [row], "job": job})))


def _preset_tag(preset: str) -> str:
    return Path(preset).stem if preset.endswith(".toml") else preset


def run_real_suite(out, cases: list[str] | None = None, presets: list[str] | None = None, data=None, force: bool = False, quick: bool = False,
                   threads: int = 1, overrides: list[str] | None = None, max_frames: int | None = None, progress: bool = True, command: str = "") -> list[dict]:
    """Run the suite into ``out``; returns the table rows. ``cases``/``presets`` pick subsets
    (default: every case; fast and balanced); ``overrides`` are ``--set`` settings for every
    layercam job; ``quick`` renders tiny composites and trains a few steps (a smoke test)."""
    from layercam.config import load_config
    from layercam.io.atomic import ensure_writable_dir
    from layercam.realsuite.table import collect_rows, write_table

    names = list(cases or CASES)
    for n in names:
        if n not in CASES:
            raise LayercamError(f"unknown real-suite case {n!r} (one of {', '.join(CASES)})")
    presets = list(presets or ["fast", "balanced"])
    ov = list(overrides or []) + (QUICK_OVERRIDES if quick else [])
    for p in presets:
        load_config(p, ov)  # a bad preset or setting fails now, not after an hour
    data = resolve_data(data)
    out = ensure_writable_dir(Path(out))
    say = print if progress else (lambda *a, **k: None)

    def job(name: str, kind: str, tag: str, **kw) -> dict:
        d = out / "cases" / name / tag
        return {"kind": kind, "case": name, "case_dir": str(out / "cases" / name), "dir": str(d), "data": str(data), "shared_dir": str(out / "shared"), "quick": quick, "max_frames": max_frames, **kw}

    def run(j: dict, what: str) -> None:
        d = Path(j["dir"])
        if force and d.exists():
            shutil.rmtree(d)
        if _done(d):
            say(f"{what}: done before, skipped (--force to redo)")
            return
        say(f"{what}: running ...", flush=True)
        _spawn(j, threads)
        res = json.loads((d / "result.json").read_text())
        for r in res["rows"]:
            msg = f"failed: {r['failed']}" if r.get("failed") else ", ".join(f"{k} {r[k]}" for k in ("psnr_mu", "psnr_mu_fg", "flicker", "wall_s") if r.get(k) is not None)
            say(f"  {r['method']} {r.get('preset', '')}: {msg}")
        rows = collect_rows(out, CASES)
        write_table(out, rows, CASES, command)
        try:
            _figure(out, j["case"], [r for r in rows if r["case"] == j["case"]], data, quick, max_frames)
        except Exception as e:  # noqa: BLE001 - a figure must not stop a long run; said, not hidden
            say(f"  figure of {j['case']} not drawn: {type(e).__name__}: {e}")

    for name in names:
        if force:
            for f in ("truth.npz", "inputs/composite.npz"):
                (out / "cases" / name / f).unlink(missing_ok=True)
        run(job(name, "prepare", "prepare"), f"{name} prepare")
        run(job(name, "classical", "classical"), f"{name} classical")
    for p in presets:
        for name in names:
            run(job(name, "layercam", f"layercam-{_preset_tag(p)}", preset=p, overrides=ov, threads=threads), f"{name} layercam {p}")
    return collect_rows(out, CASES)


def _figure(out: Path, name: str, rows: list[dict], data: Path, quick: bool, max_frames: int | None) -> None:
    """Draw the case's figure from the outputs on disk (skipped until its inputs are prepared)."""
    import numpy as np

    from layercam.realsuite.cases import case_inputs, load_inputs, load_truth, read_prediction
    from layercam.realsuite.figures import case_figure

    case, case_dir = CASES[name], out / "cases" / name
    if not _done(case_dir / "prepare"):
        return
    ci = case_inputs(case, case_dir, data, quick, max_frames)
    frames, times, _ = load_inputs(case, ci)
    truth = load_truth(case, case_dir, data, frames, times)
    preds = {}
    for r in rows:
        if r.get("failed"):
            continue
        if r["method"] == "layercam":
            run_dir = case_dir / f"layercam-{_preset_tag(r['preset'])}" / "run"
            preds[f"layercam {r['preset']}"] = read_prediction(case, run_dir, len(frames))
        else:
            preds[r["method"]] = np.load(case_dir / "classical" / f"{r['method']}.npy")
    if preds:
        case_figure(case, case_dir, rows, frames, truth, preds, case_dir / "figure.png")
