"""``layercam bench --table joins``: window joins on long real clips, one model against two windows
sharing one camera.

Each case is a clip of ``frames`` frames (default :data:`FRAMES`), run twice with ``layercam hdr-video``
(one process each, ``threads`` torch threads, ``nice -n 10``): ``--window off`` (one model) and
``--window N`` with N = :func:`two_windows` (two windows overlapping by a third of their length,
57 frames each for 96; the second holds window 0's
camera fixed).

* ``composite``: the real-suite composite (``layercam.bench.realsuite.composite``: DAVIS parkour's person
  over bracket_taipei's radiance map, a pan, a filmic camera, noise, 8 bits, alternating 2 EV)
  made ``frames`` long, the person's 30 frames played forth and back; ground truth per frame.
  Scores: PSNR-mu of each frame against the truth (one scale per channel for the whole clip).
* ``basler``: ``altexp_video_basler/clip_2exp_3stop.mp4`` (74 frames, alternating 3 EV), played
  back and forth to ``frames`` (:func:`centred`: 11 + 74 + 11 frames for 96, so that each window
  holds 46 distinct frames). No truth: each frame's PSNR-mu against the one-model run's frame.

Both: flicker of each pair of neighbouring frames (``layercam.bench.realsuite.measures.flicker``: the
preview's tonemap over the whole clip, 8-bit codes on the input's registered static pixels), so
that the pairs at the windows' join (the overlap and the pair on each side of it) can be compared
with the clip's median pair, and with the median over the pairs of their own phase (short -> long
and long -> short pairs flicker differently). A finished run is reused (``force``: run again).
``--quick``: 24 frames, a smaller composite and a few steps (a smoke test, not a measurement).
Writes OUT/<case>/{frames/,truth.npy,single/,windows/}, OUT/joins.json, OUT/joins.md and OUT/joins.png.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from layercam.core.errors import LayercamError

CASES = ["composite", "basler"]
FRAMES = 96
QUICK_FRAMES = 24
QUICK = ["train.steps=20", "train.bootstrap_steps=2", "train.batch=512"]


def two_windows(T: int, cycle: int = 2) -> int:
    """The shortest window length that cuts ``T`` frames (exposures repeating every ``cycle``) into
    two windows overlapping by :func:`layercam.pipelines.windows.plan.overlap_for` (57 for 96: windows
    of 57 frames overlapping by 18)."""
    from layercam.pipelines.windows.plan import overlap_for

    n = (T + 1) // 2
    while 2 * n - overlap_for(n, cycle) < T:
        n += 1
    return n


def forth_and_back(n: int, length: int, first: int = 0) -> list[int]:
    """Frame indices ``first``, ``first - 1``, ..., 0, 1, ..., n-1, n-2, ... (``length`` of them;
    ``first`` 0: 0, 1, ..., n-1, n-2, ..., 0, 1, ...)."""
    cycle = list(range(n)) + list(range(n - 2, 0, -1))
    start = (len(cycle) - first) % len(cycle)
    return [cycle[(start + i) % len(cycle)] for i in range(length)]


def centred(n: int, length: int) -> list[int]:
    """A clip of ``n`` frames made ``length`` long (``n < length``) with its two turnarounds placed
    alike: it starts ``(length - n) // 2`` frames in, played back to frame 0, then forth and back.
    Two windows that split it then hold as many distinct frames each (a model fits a frame it sees
    twice better, and the join is judged between windows that fit their frames alike)."""
    return forth_and_back(n, length, (length - n) // 2 if n < length else 0)


def build(case: str, folder: Path, data: Path, T: int, quick: bool = False) -> dict:
    """The case's ``T`` frames as PNGs under ``folder/frames`` (and ``truth.npy`` for the composite);
    ``folder/clip.json`` says what they are (a clip already built is reused)."""
    from layercam.io import write_png

    frames_dir = folder / "frames"
    info = folder / "clip.json"
    if info.exists():
        return json.loads(info.read_text())
    frames_dir.mkdir(parents=True, exist_ok=True)
    if case == "composite":
        from layercam.bench.realsuite.composite import CompositeSpec, compose, load_background, load_foreground

        spec = CompositeSpec(frames=T, ev_step=2.0, **({"size": (48, 64)} if quick else {}))
        rgb, alpha = load_foreground(data, spec.fg_clip, 30)
        idx = forth_and_back(30, T)
        c = compose(load_background(data), rgb[idx], alpha[idx], spec)
        for t, f in enumerate(c["frames"]):
            write_png(frames_dir / f"frame_{t:03d}.png", f.astype(np.float32) / 255.0)
        np.save(folder / "truth.npy", c["hdr"])
        meta = {"ev_step": 2.0, "truth": True, "source": "composite parkour over taipei, 2 EV, forth and back"}
    else:
        from layercam.io import load_clip

        clip = load_clip(data / "altexp_video_basler" / "clip_2exp_3stop.mp4")
        idx = centred(clip.T, T)
        for t, i in enumerate(idx):
            write_png(frames_dir / f"frame_{t:03d}.png", clip.frames[i])
        meta = {"ev_step": 3.0, "truth": False,
                "source": f"altexp_video_basler/clip_2exp_3stop.mp4 ({clip.T} frames) back and "
                          "forth, centred"}
    meta["indices"] = idx
    info.write_text(json.dumps(meta))
    return meta


def run(folder: Path, name: str, meta: dict, preset: str, window: str,
        overrides: list[str] | None = None, threads: int = 1, force: bool = False) -> dict:
    """``layercam hdr-video`` on the case's frames with ``--window window`` into ``folder/name``
    (a finished run is reused unless ``force``): its wall time."""
    out = folder / name
    if force and out.exists():
        shutil.rmtree(out)
    if (out / "report.json").exists():
        rep = json.loads((out / "report.json").read_text())
        return {"wall_s": rep["wall_seconds"], "cached": True}
    env = dict(os.environ, OMP_NUM_THREADS=str(threads))
    argv = [sys.executable, "-m", "layercam", "hdr-video", str(folder / "frames"), "--exposures",
            "alt", "--ev-step", f"{meta['ev_step']:g}",
            "--preset", preset, "--window", window, "--out", str(out), "--quiet",
            *[a for s in overrides or [] for a in ("--set", s)]]
    t0 = time.perf_counter()
    r = subprocess.run(["nice", "-n", "10", *argv], env=env, capture_output=True, text=True)
    if r.returncode:
        raise LayercamError(f"{folder.name}/{name}: hdr-video failed: {(r.stderr.strip().splitlines() or ['?'])[-1]}")
    return {"wall_s": round(time.perf_counter() - t0, 1), "cached": False, "argv": " ".join(argv[1:])}


def read_hdr(run: Path) -> np.ndarray:
    from layercam.io import read_exr

    return np.stack([read_exr(p) for p in sorted((run / "hdr").glob("*.exr"))])


def per_frame_psnr_mu(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """PSNR-mu of each frame, the prediction aligned to ``gt`` by one scale per channel over the
    whole clip and both normalised by gt's maximum (``layercam.core.metrics``' convention)."""
    from layercam.core.metrics import align_scale, mu_law

    p = np.clip(align_scale(pred, gt) / float(gt.max()), 0, 1)
    g = np.clip(gt / float(gt.max()), 0, 1)
    mse = ((mu_law(p) - mu_law(g)) ** 2).reshape(len(p), -1).mean(1)
    return 10 * np.log10(1.0 / np.maximum(mse, 1e-20))


def pair_flicker(hdr: np.ndarray, hom: np.ndarray, static: np.ndarray) -> np.ndarray:
    """Flicker (8-bit codes) of each pair (t, t+1) with a static mask; NaN where none is static."""
    from layercam.bench.realsuite.measures import flicker
    from layercam.scene.render import tonemap_display

    _, stats = tonemap_display(hdr)
    disp = np.stack([tonemap_display(x, stats)[0] for x in hdr])
    return np.array([flicker(disp[t : t + 2], hom[t : t + 1], static[t : t + 1]) for t in range(len(static))])


def score(case: str, folder: Path, meta: dict) -> dict:
    from layercam.io import load_clip
    from layercam.bench.realsuite.jobs import static_pixels

    frames = load_clip(folder / "frames").frames
    hom, static = static_pixels(frames, folder)
    single, win = read_hdr(folder / "single"), read_hdr(folder / "windows")
    index = json.loads((folder / "windows" / "windows.json").read_text())
    (a, b), = [(w["frames"][0], index["windows"][w["index"] - 1]["frames"][1]) for w in index["windows"][1:]]
    ref = np.load(folder / "truth.npy") if meta["truth"] else single
    ps_single = per_frame_psnr_mu(single, ref) if meta["truth"] else np.full(len(single), np.inf)
    ps_win = per_frame_psnr_mu(win, ref)
    fl_single, fl_win = pair_flicker(single, hom, static), pair_flicker(win, hom, static)
    join = list(range(a - 1, b))  # pairs (t, t+1) touching the overlap [a, b)
    res = {
        "case": case, "source": meta["source"], "overlap": [a, b], "join_pairs": join,
        "psnr_single": ps_single.tolist(), "psnr_windows": ps_win.tolist(),
        "flicker_single": fl_single.tolist(), "flicker_windows": fl_win.tolist(),
        "static_share": float(static.mean()),
    }
    if meta["truth"]:
        d = ps_win - ps_single
        res.update(psnr_single_mean=float(ps_single.mean()), psnr_windows_mean=float(ps_win.mean()),
                   worst_frame=int(np.argmin(d)), worst_drop_db=float(-d.min()),
                   frames_over_0p5_db_under=int((d < -0.5).sum()))
    else:
        res.update(agreement_psnr_mean=float(ps_win.mean()), agreement_psnr_min=float(ps_win.min()),
                   agreement_worst_frame=int(np.argmin(ps_win)))
    for name, fl in (("single", fl_single), ("windows", fl_win)):
        res[f"flicker_{name}_median"] = float(np.nanmedian(fl))
        res[f"flicker_{name}_clip"] = float(np.nanmean(fl))
        res[f"flicker_{name}_join_max"] = float(np.nanmax(fl[join]))
        res[f"flicker_{name}_join_mean"] = float(np.nanmean(fl[join]))
        # a pair short -> long flickers differently from long -> short: each join pair against the
        # clip's median over the pairs of its own phase
        phase = np.array([np.nanmedian(fl[p::2]) for p in range(2)])
        rel = np.array([fl[t] / phase[t % 2] for t in join])
        res[f"flicker_{name}_join_rel_mean"] = float(np.nanmean(rel))
        res[f"flicker_{name}_join_rel_max"] = float(np.nanmax(rel))
    return res


def figure(results: list[dict], path: Path) -> None:
    """Per case: PSNR-mu per frame (top) and flicker per pair (bottom), the overlap shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(results), figsize=(6.5 * len(results), 6), squeeze=False)
    for j, r in enumerate(results):
        a, b = r["overlap"]
        ax = axes[0, j]
        if np.isfinite(r["psnr_single"]).all():
            ax.plot(r["psnr_single"], label="one model", color="k", lw=1)
            ax.plot(r["psnr_windows"], label="two windows", color="tab:red", lw=1)
            ax.set_ylabel("PSNR-mu vs truth (dB)")
        else:
            ax.plot(r["psnr_windows"], label="two windows vs one model", color="tab:red", lw=1)
            ax.set_ylabel("PSNR-mu vs one model (dB)")
        ax.axvspan(a - 0.5, b - 0.5, color="tab:blue", alpha=0.15, label="overlap (cross-fade)")
        ax.set_title(f"{r['case']}: per frame")
        ax.legend(fontsize=8)
        ax = axes[1, j]
        ax.plot(np.arange(len(r["flicker_single"])) + 0.5, r["flicker_single"], color="k", lw=1, label="one model")
        ax.plot(np.arange(len(r["flicker_windows"])) + 0.5, r["flicker_windows"], color="tab:red",
                lw=1, label="two windows")
        ax.axhline(r["flicker_windows_median"], color="tab:red", ls=":", lw=1, label="two windows: median pair")
        ax.axvspan(a - 0.5, b - 0.5, color="tab:blue", alpha=0.15)
        ax.set_ylabel("flicker, pair (t, t+1) (8-bit codes)")
        ax.set_xlabel("frame")
        ax.legend(fontsize=8)
    fig.tight_layout()
    from layercam.io.atomic import atomic_write

    atomic_write(path, lambda p: fig.savefig(p, dpi=90))
    plt.close(fig)


def table(results: list[dict], runs: dict) -> str:
    """The markdown table: a row per case and run (one model, two windows)."""
    rows = ["| clip | run | wall | PSNR-mu mean (dB) | worst frame against one model | flicker, "
            "codes: clip's median pair / join pairs' mean / max | join pairs / their phase's "
            "median: mean, max |", "|---|---|---|---|---|---|---|"]
    for r in results:
        c = r["case"]
        for name in ("single", "windows"):
            wall = runs[c][name]["wall_s"]
            if "psnr_single_mean" in r:
                ps = f"{r[f'psnr_{name}_mean']:.2f}"
                worst = ("" if name == "single"
                         else f"{-r['worst_drop_db']:+.2f} dB (frame {r['worst_frame']}; "
                              f"{r['frames_over_0p5_db_under']} frames > 0.5 dB under)")
            else:
                ps = "(reference)" if name == "single" else f"{r['agreement_psnr_mean']:.2f} vs one model"
                worst = ("" if name == "single"
                         else f"min {r['agreement_psnr_min']:.2f} dB (frame "
                              f"{r['agreement_worst_frame']})")
            fl = (f"{r[f'flicker_{name}_median']:.3f} / {r[f'flicker_{name}_join_mean']:.3f} / "
                  f"{r[f'flicker_{name}_join_max']:.3f}")
            rel = f"{r[f'flicker_{name}_join_rel_mean']:.3f}, {r[f'flicker_{name}_join_rel_max']:.3f}"
            rows.append(f"| {c} | {'one model' if name == 'single' else 'two windows'} | "
                        f"{wall:.0f} s | {ps} | {worst} | {fl} | {rel} |")
    return "\n".join(rows)




def run_joins(out: Path, data: Path, cases: list[str] | None = None, preset: str = "fast",
              frames: int | None = None, overrides: list[str] | None = None,
              quick: bool = False, force: bool = False, threads: int = 1, progress: bool = True) -> list[dict]:
    """Each case built, run twice and scored; writes joins.{json,md,png} under ``out``. The scores per case."""
    from layercam.io.atomic import atomic_write

    cases = cases or CASES
    bad = [c for c in cases if c not in CASES]
    if bad:
        raise LayercamError(f"--table joins: unknown case {bad[0]!r} (cases: {', '.join(CASES)})")
    if not Path(data).is_dir():
        raise LayercamError(f"shared captures not found at {data} (--data or $LAYERCAM_DATA)")
    T = frames or (QUICK_FRAMES if quick else FRAMES)
    window = str(two_windows(T))
    overrides = (QUICK if quick else []) + list(overrides or [])
    out = Path(out)
    results, runs = [], {}
    for case in cases:
        folder = out / case
        meta = build(case, folder, Path(data), T, quick)
        if len(meta["indices"]) != T:
            raise LayercamError(f"{folder} holds a clip of {len(meta['indices'])} frames, not {T}: "
                                "another --out, or delete it")
        runs[case] = {"single": run(folder, "single", meta, preset, "off", overrides, threads, force),
                      "windows": run(folder, "windows", meta, preset, window, overrides, threads, force)}
        if progress:
            print(case, runs[case], flush=True)
        results.append(score(case, folder, meta))
    atomic_write(out / "joins.json",
                 lambda p: p.write_text(json.dumps({"results": results, "runs": runs,
                                                    "preset": preset, "window": window}, indent=1)))
    md = table(results, runs)
    atomic_write(out / "joins.md", lambda p: p.write_text(md + "\n"))
    figure(results, out / "joins.png")
    if progress:
        print(md)
    return results
