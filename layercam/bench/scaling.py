"""``layercam bench --table scaling``: what a run costs as the picture grows.

For each frame size (default 128x128, 256x256, 512x512, 1920x1080) a synthetic alternating-exposure
clip (``synth.pan_hdr``, 48 frames) is written to disk with its ground truth
(:mod:`layercam.synth.disk`); then each preset runs ``layercam hdr-video`` on the frames as a user
would (PNG folder + ``times.txt``), in its own process so that its peak memory (``ru_maxrss``) is
its own. Recorded per case: training steps/s and samples/s (wall and CPU time), seconds per stage,
end-to-end wall time, peak memory, and PSNR-mu of the exported HDR against the ground truth (read
frame by frame); per size, OpenCV Debevec on DIS-aligned neighbours next to it. Writes
``scaling.csv``, ``scaling.json`` and ``scaling.png`` (log-log: cost against pixels per frame) after
each case; a later run into the same folder replaces the rows of the cases it runs and keeps the
others (e.g. ``--presets fast`` first, then ``--presets balanced``).
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from layercam.core.errors import LayercamError

SIZES = ["128x128", "256x256", "512x512", "1080x1920"]  # HxW
PRESETS = ["fast", "balanced"]
FIELDS = ["size", "pixels", "method", "preset", "grid_max_res", "wall_s", "flow_s", "bootstrap_s",
          "train_s", "export_s",
          "steps", "batch", "steps_per_s", "samples_per_s", "train_cpu_ms_per_step", "peak_mem_mb",
          "psnr_mu", "psnr_l", "ssim_mu", "note"]


def parse_size(s: str) -> tuple[int, int]:
    """``"HxW"`` -> ``(H, W)``."""
    try:
        h, w = (int(v) for v in s.lower().split("x"))
    except ValueError:
        raise LayercamError(f"a size is HxW (e.g. 1080x1920), got {s!r}") from None
    if h < 8 or w < 8:
        raise LayercamError(f"sizes start at 8x8, got {s!r}")
    return h, w


def _spawn(fn: str, job: dict, result: Path) -> dict:
    """Runs ``layercam.bench.scaling.<fn>(job)`` in a fresh process; returns what it wrote."""
    code = f"import json, sys; from layercam.bench.scaling import {fn}; {fn}(json.loads(sys.argv[1]))"
    p = subprocess.run([sys.executable, "-c", code, json.dumps({**job, "result": str(result)})],
                       capture_output=True, text=True)
    if p.returncode != 0:
        tail = (p.stderr or p.stdout).strip().splitlines()[-1:] or ["?"]
        raise LayercamError(f"scaling job {fn} {job.get('size', '')} {job.get('preset', '')} failed: {tail[0]}")
    return json.loads(result.read_text())


def _finish(job: dict, res: dict) -> None:
    # this job's, or its run's
    res.setdefault("peak_mem_mb",
                   round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1))
    Path(job["result"]).write_text(json.dumps(res))


# -- the jobs, each in its own process ------------------------------------------------------------
def clip_job(job: dict) -> None:
    from layercam.synth.disk import write_pan_hdr

    t0 = time.perf_counter()
    info = write_pan_hdr(Path(job["clip"]), job["frames"], tuple(job["hw"]), seed=0)
    _finish(job, {"seconds": round(time.perf_counter() - t0, 2), "gain": info["gain"]})


def run_job(job: dict) -> None:
    """``layercam hdr-video`` on the clip's frames, in a process of its own (its peak memory is the run's)."""
    from layercam.bench.command import run_layercam

    clip = Path(job["clip"])
    argv = ["hdr-video", str(clip / "frames"), "--exposures", str(clip / "times.txt"), "--preset",
            job["preset"], "--out", job["out"], "--quiet"]
    for s in job["overrides"]:
        argv += ["--set", s]
    ran = run_layercam(argv, job["threads"], Path(job["out"]) / "report.json")
    if ran["returncode"] != 0:
        raise SystemExit(ran["returncode"])
    _finish(job, {"wall_s": round(ran["wall_s"], 2), "peak_mem_mb": ran["peak_mem_mb"]})


def score_job(job: dict) -> None:
    """PSNR-mu etc. of a run's ``hdr/`` (or the baseline's) against the clip's ground truth."""
    from layercam.io import read_exr
    from layercam.core.frame_metrics import hdr_metrics_streamed
    from layercam.synth.disk import truth_frame

    hdr = Path(job["hdr"])
    m = hdr_metrics_streamed(lambda t: read_exr(hdr / f"frame_{t:05d}.exr"),
                             lambda t: truth_frame(Path(job["clip"]), t), job["frames"])
    _finish(job, m)


def debevec_job(job: dict) -> None:
    """OpenCV Debevec on each frame and its DIS-aligned neighbour (``baselines.debevec_video``), in
    chunks of ``chunk`` frames (each with its neighbour; the CRF calibrated per chunk) so that a
    1080p clip fits; EXRs into ``job["out"]``."""
    from layercam.bench.baselines import debevec_video
    from layercam.io import read_image, write_exr

    clip, out = Path(job["clip"]), Path(job["out"])
    out.mkdir(parents=True, exist_ok=True)
    times = np.array([float(line.split()[1]) for line in (clip / "times.txt").read_text().splitlines() if line.strip()])
    n, step = job["frames"], job.get("chunk", 12)
    t0 = time.perf_counter()
    for a in range(0, n, step):
        b = min(a + step, n)
        # with each frame's neighbour (the last frame's: the one before)
        lo, hi = (a if b < n or b - a >= 2 else a - 1), min(b + 1, n)
        f = np.stack([read_image(clip / "frames" / f"frame_{t:05d}.png") for t in range(lo, hi)])
        hdr = debevec_video(f, times[lo:hi], flow_method="dis_medium")
        for t in range(a, b):
            write_exr(out / f"frame_{t:05d}.exr", hdr[t - lo], half=False)
    _finish(job, {"wall_s": round(time.perf_counter() - t0, 2)})


# -- the table ----------------------------------------------------------------------------------
def _row(size: str, hw, preset: str, run: Path, res: dict, score: dict, note: str) -> dict:
    rep = json.loads((run / "report.json").read_text())
    tr, st = rep["train"], rep["stages"]
    sec = lambda k: round(st.get(k, {}).get("seconds", 0.0), 2)  # noqa: E731
    batch = rep["settings"]["train"]["batch"]
    cpu = tr.get("cpu_seconds_this_session")
    return {
        "size": size, "pixels": hw[0] * hw[1], "method": "layercam", "preset": preset,
        "grid_max_res": _grid_res(run), "wall_s": res["wall_s"], "flow_s": sec("flow"), "bootstrap_s": sec("bootstrap"),
        "train_s": sec("train"), "export_s": round(sec("export") + sec("atlas"), 2),
        "steps": tr["steps"], "batch": batch,
        "steps_per_s": tr["steps_per_s"], "samples_per_s": round(tr["steps_per_s"] * batch),
        "train_cpu_ms_per_step": round(1000 * cpu / max(tr["steps"] - tr["resumed_from"], 1), 2) if cpu else "",
        "peak_mem_mb": res["peak_mem_mb"], **{k: round(v, 3) for k, v in score.items()}, "note": note,
    }


def _grid_res(run: Path) -> int | str:
    import torch

    ck = torch.load(run / "checkpoint.pt", map_location="cpu", weights_only=False)
    return int(ck["sizes"]["grid_max_res"])


def run_scaling(out: Path, sizes: list[str] | None = None, presets: list[str] | None = None,
                frames: int = 48, threads: int = 2,
                overrides: list[str] | None = None, baseline: bool = True, progress: bool = True) -> list[dict]:
    from layercam.io.atomic import ensure_writable_dir

    out = ensure_writable_dir(Path(out))
    say = print if progress else (lambda *a, **k: None)
    rows = _previous_rows(out)

    def add(row):  # replaces the same case's earlier row; the table is written after each case
        rows[:] = [r for r in rows if _key(r) != _key(row)] + [row]
        rows.sort(key=lambda r: (r["pixels"], r["method"] != "debevec"))  # stable: presets in the order run
        write_scaling(out, rows)
    for size in sizes or SIZES:
        hw = parse_size(size)
        clip = out / "clips" / f"{hw[0]}x{hw[1]}-{frames}"
        c = _spawn("clip_job", {"clip": str(clip), "frames": frames, "hw": list(hw), "size": size}, out / "result.json")
        say(f"{size:>10} clip written in {c['seconds']:.1f} s (peak {c['peak_mem_mb']:.0f} MB)")
        if baseline:
            d = _spawn("debevec_job",
                       {"clip": str(clip), "frames": frames, "out": str(out / "debevec" / size),
                        "size": size}, out / "result.json")
            s = _spawn("score_job",
                       {"clip": str(clip), "frames": frames, "hdr": str(out / "debevec" / size)},
                       out / "result.json")
            add({"size": size, "pixels": hw[0] * hw[1], "method": "debevec", "preset": "",
                 "wall_s": d["wall_s"], "peak_mem_mb": d["peak_mem_mb"],
                         **{k: round(s[k], 3) for k in ("psnr_mu", "psnr_l", "ssim_mu")},
                         "note": "DIS flow + OpenCV Debevec per frame and aligned neighbour, CRF "
                                 "per 12-frame chunk"})
            say(f"{size:>10} {'debevec':>9} {d['wall_s']:8.1f} s  PSNR-mu {s['psnr_mu']:.2f}")
        for preset in presets or PRESETS:
            run = out / "runs" / f"{size}-{preset}"
            job = {"clip": str(clip), "preset": preset, "out": str(run), "threads": threads,
                   "overrides": list(overrides or []), "size": size}
            res = _spawn("run_job", job, out / "result.json")
            score = _spawn("score_job",
                           {"clip": str(clip), "frames": frames, "hdr": str(run / "hdr")},
                           out / "result.json")
            score = {k: score[k] for k in ("psnr_mu", "psnr_l", "ssim_mu")}
            r = _row(size, hw, preset, run, res, score, f"{threads} thread(s); " + " ".join(overrides or []))
            add(r)
            say(f"{size:>10} {preset:>9} {r['wall_s']:8.1f} s  train {r['steps_per_s']} steps/s "
                f"({r['train_cpu_ms_per_step']} ms CPU/step)  peak {r['peak_mem_mb']:.0f} MB  "
                f"PSNR-mu {r['psnr_mu']:.2f}")
    return rows


def _key(row: dict) -> tuple:
    return row["size"], row["method"], row["preset"]


def _previous_rows(out: Path) -> list[dict]:
    """The rows of an earlier run into ``out`` (``scaling.json``): a run of other sizes or presets
    adds its rows to them, so that the table can be made a preset at a time."""
    p = out / "scaling.json"
    return json.loads(p.read_text()) if p.exists() else []


def write_scaling(out: Path, rows: list[dict]) -> None:
    from layercam.bench.synthetic import write_csv
    from layercam.io.atomic import atomic_write

    write_csv(out / "scaling.csv", rows, FIELDS)
    atomic_write(out / "scaling.json", lambda p: p.write_text(json.dumps(rows, indent=1)))
    plot_scaling(out / "scaling.png", rows)


def plot_scaling(path: Path, rows: list[dict]) -> None:
    """Log-log panels against pixels per frame: ms per training step, end-to-end wall time, peak memory."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    from layercam.io.atomic import atomic_write

    panels = [("ms per training step (wall)", lambda r: 1000.0 / r["steps_per_s"] if r.get("steps_per_s") else None),
              ("end-to-end wall time (s)", lambda r: r.get("wall_s")),
              ("peak memory (MB)", lambda r: r.get("peak_mem_mb"))]
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.8), dpi=110)
    labels = sorted({(r["method"], r["preset"]) for r in rows})
    colours = {lab: f"C{i}" for i, lab in enumerate(labels)}  # one colour per series in every panel
    sizes = {r["pixels"]: r["size"] for r in rows}
    for ax, (title, get) in zip(axes, panels):
        for method, preset in labels:
            pts = sorted(((r["pixels"], get(r)) for r in rows
                          if (r["method"], r["preset"]) == (method, preset) and get(r)),
                         key=lambda p: p[0])
            if pts:
                ax.plot([p[0] for p in pts], [p[1] for p in pts],
                        "o-" if method == "layercam" else "s--", label=preset or method,
                        color=colours[(method, preset)])
        x = np.array(sorted({r["pixels"] for r in rows}), dtype=float)
        if title.startswith("ms") and len(x) > 1:
            base = [get(r) for r in rows if r["pixels"] == x[0] and r["method"] == "layercam" and get(r)]
            if base:  # what cost proportional to the pixels would look like
                ax.plot(x, min(base) * x / x[0], ":", color="grey", label="proportional to pixels")
        ax.set_xscale("log")
        ax.set_yscale("log")
        # the sizes measured, not 2x10^4 ...
        ax.set_xticks(sorted(sizes), [sizes[k] for k in sorted(sizes)], fontsize=7)
        ax.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
        ax.set_xlabel("pixels per frame (HxW)")
        ax.set_title(title, fontsize=9)
        ax.grid(alpha=0.3, which="both")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    fig.suptitle("layercam: cost against frame size (synthetic pan, alternating exposures)", fontsize=10)
    fig.tight_layout()
    atomic_write(Path(path), lambda p: fig.savefig(p))
    plt.close(fig)
