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

from layercam.core.presets import preset_tag
from layercam.core.errors import LayercamError
from layercam.io.lock import pid_alive
from layercam.bench.realsuite.cases import CASES

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
        p = subprocess.run([sys.executable, "-m", "layercam.bench.realsuite.jobs", json.dumps(job)],
                           stdout=log, stderr=subprocess.STDOUT, env=env)
    if p.returncode != 0:
        lines = (d / "log.txt").read_text(errors="replace").strip().splitlines() or ["?"]
        row = {"method": job["kind"] if job["kind"] != "layercam" else "layercam",
               "preset": job.get("preset", ""), "failed": lines[-1][:200]}
        atomic_write(d / "result.json", lambda q: q.write_text(json.dumps({"rows": [row], "job": job})))


class _Lock:
    """``out/suite.lock`` holds the pid of the run writing into ``out``: a second run into the same
    folder is refused (its jobs would share run folders); a lock left by a dead process is taken."""

    def __init__(self, out: Path):
        self.path = out / "suite.lock"

    def __enter__(self):
        for _ in range(2):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            except FileExistsError:
                pid = int(self.path.read_text().strip() or 0)
                if pid_alive(pid):
                    raise LayercamError(f"another real-suite run (pid {pid}) is writing into "
                                        f"{self.path.parent}") from None
                self.path.unlink(missing_ok=True)
                continue
            os.write(fd, str(os.getpid()).encode())
            os.close(fd)
            return self
        raise LayercamError(f"cannot lock {self.path}")

    def __exit__(self, *exc):
        self.path.unlink(missing_ok=True)


def run_real_suite(out, cases: list[str] | None = None, presets: list[str] | None = None, data=None,
                   force: bool = False, quick: bool = False,
                   threads: int = 1, overrides: list[str] | None = None,
                   max_frames: int | None = None, progress: bool = True, command: str = "",
                   redraw: bool = False) -> list[dict]:
    """Run the suite into ``out``; returns the table rows. ``cases``/``presets`` pick subsets
    (default: every case; fast and balanced); ``overrides`` are ``--set`` settings for every
    layercam job; ``quick`` renders tiny composites and trains a few steps (a smoke test);
    ``redraw`` runs nothing and writes the table and figures from the finished jobs."""
    from layercam.core.presets import load_config
    from layercam.io.atomic import ensure_writable_dir

    names = list(cases or CASES)
    for n in names:
        if n not in CASES:
            raise LayercamError(f"unknown real-suite case {n!r} (one of {', '.join(CASES)})")
    presets = list(presets or ["fast", "balanced"])
    ov = list(overrides or []) + (QUICK_OVERRIDES if quick else [])
    for p in presets:
        load_config(p, ov)  # a bad preset or setting fails now, not after an hour
    s = _Suite(ensure_writable_dir(Path(out)), resolve_data(data), quick, max_frames, threads,
               command, print if progress else (lambda *a, **k: None))
    if redraw:
        return s.outputs(names)
    with _Lock(s.out):
        for name in names:
            if force:
                for f in ("truth.npz", "inputs/composite.npz", "inputs/shake.npz"):
                    (s.out / "cases" / name / f).unlink(missing_ok=True)
            s.run(s.job(name, "prepare", "prepare"), f"{name} prepare", force)
            s.run(s.job(name, "classical", "classical"), f"{name} classical", force)
        for p in presets:
            for name in names:
                s.run(s.job(name, "layercam", f"layercam-{preset_tag(p)}", preset=p, overrides=ov,
                            threads=threads), f"{name} layercam {p}", force)
    return s.outputs(names)  # tables and figures drawn again from everything on disk


class _Suite:
    """Where a suite run writes, what it reads, and how it says what it does."""

    def __init__(self, out: Path, data: Path, quick: bool, max_frames: int | None, threads: int, command: str, say):
        self.out, self.data, self.quick, self.max_frames, self.threads, self.command, self.say = (
            out, data, quick, max_frames, threads, command, say)

    def job(self, name: str, kind: str, tag: str, **kw) -> dict:
        d = self.out / "cases" / name / tag
        return {"kind": kind, "case": name, "case_dir": str(self.out / "cases" / name),
                "dir": str(d), "data": str(self.data),
                "shared_dir": str(self.out / "shared"), "quick": self.quick, "max_frames": self.max_frames, **kw}

    def run(self, j: dict, what: str, force: bool) -> None:
        """Run job ``j`` unless it finished before; then the table and the case's figure."""
        d = Path(j["dir"])
        if force and d.exists():
            shutil.rmtree(d)
        if _done(d):
            self.say(f"{what}: done before, skipped (--force to redo)")
            return
        self.say(f"{what}: running ...", flush=True)
        _spawn(j, self.threads)
        for r in json.loads((d / "result.json").read_text())["rows"]:
            msg = f"failed: {r['failed']}" if r.get("failed") else ", ".join(f"{k} {r[k]}"
                for k in ("psnr_mu", "psnr_mu_fg", "flicker", "psnr", "gain_db", "wall_s")
                if r.get(k) is not None)
            self.say(f"  {r['method']} {r.get('preset', '')}: {msg}", flush=True)
        self.outputs([j["case"]])

    def outputs(self, which: list[str]) -> list[dict]:
        """Write the table from every finished job, and the figures of the cases ``which``."""
        from layercam.bench.realsuite.table import collect_rows, write_table

        rows = collect_rows(self.out, CASES)
        write_table(self.out, rows, CASES, self.command)
        for name in which:
            try:
                _figure(self.out, name, [r for r in rows if r["case"] == name], self.data, self.quick, self.max_frames)
            except Exception as e:  # noqa: BLE001 - a figure must not stop a long run; said, not hidden
                self.say(f"  figure of {name} not drawn: {type(e).__name__}: {e}")
        return rows


def _figure(out: Path, name: str, rows: list[dict], data: Path, quick: bool, max_frames: int | None) -> None:
    """Draw the case's figure from the outputs on disk (skipped until its inputs are prepared)."""
    import numpy as np

    from layercam.bench.realsuite.cases import case_inputs, load_inputs, load_truth, read_prediction
    from layercam.bench.realsuite.figures import case_figure
    from layercam.io import read_image

    case, case_dir = CASES[name], out / "cases" / name
    if not _done(case_dir / "prepare"):
        return
    ci = case_inputs(case, case_dir, data, quick, max_frames)
    frames, times, _ = load_inputs(case, ci)
    truth = load_truth(case, case_dir, data, frames, times)
    preds, masks = {}, {}
    for r in rows:
        if r.get("failed") or r["method"] == "input":  # the input: a panel of its own
            continue
        if r["method"] == "layercam":
            run_dir = case_dir / f"layercam-{preset_tag(r['preset'])}" / "run"
            preds[f"layercam {r['preset']}"] = read_prediction(case, run_dir, len(frames))
            if (run_dir / "trust").is_dir():  # a deblurring run's trust masks
                masks[r["preset"]] = np.stack([read_image(run_dir / "trust" / f"frame_{t:05d}.png")[
                    ..., 0] for t in range(len(frames))])
        else:
            preds[r["method"]] = np.load(case_dir / "classical" / f"{r['method']}.npy")
    if preds:
        case_figure(case, case_dir, rows, frames, truth, preds, case_dir / "figure.png", masks)
