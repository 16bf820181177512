"""``layercam bench --table hdr-video``: what hdr.mp4 costs and how faithful it is, on a real clip.

The clip: ``altexp_video_basler/clip_2exp_3stop.mp4`` under ``--data`` (alternating 3 EV), run as
``layercam hdr-video CLIP --exposures alt --ev-step 3 --preset P --out OUT/run`` (``--quick``: a tiny
synthetic alternating-exposure clip, a few steps: a smoke test, not a measurement). Trains the clip
once (later calls reuse the run's cache; ``--force`` trains again), then redoes only its export,
``repeat`` times per ``--hdr-format`` (none, pq, hlg), and reports per format the export's wall time,
hdr.mp4's own share (its three passes: peak, light levels, encode), the file's bitrate, and the round
trip: hdr.mp4 decoded (10-bit), through the inverse transfer and BT.2020 -> BT.709, divided by the
anchoring's one scale, against the EXRs' radiance: the median relative error of the luminance (and
of the RGB sum) on the well-exposed pixels (from 4 stops under diffuse white to where the roll-off
starts). The figure: one frame of preview.mp4 next to hdr.mp4 as an SDR screen shows it (PQ
tone-mapped with the BT.2390 EETF, diffuse white at SDR's white; HLG's signal shown as is).
Writes ``OUT/hdr_video.json``, ``OUT/hdr_video.md`` and ``OUT/hdr_video.png``. Each layercam call is
its own process (``threads`` torch threads).
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

CLIP = "altexp_video_basler/clip_2exp_3stop.mp4"
FORMATS = ["none", "pq", "hlg"]
FIGURE_FRAME = 20  # the figure's frame (the clip's last when it is shorter)
QUICK = ["train.steps=20", "train.bootstrap_steps=2", "train.batch=512"]


def quick_clip(out: Path) -> Path:
    """A tiny alternating-exposure clip (``synth.pan_hdr``, 8 frames 64x96, 3 EV) as an mp4."""
    from layercam import synth
    from layercam.io import write_video

    path = out / "quick_clip.mp4"
    if not path.exists():
        write_video(path, synth.pan_hdr(frames=8, size=(64, 96), ev_step=3.0, seed=0).clip.frames, fps=8)
    return path


def _export(run: Path, argv: list[str], fmt: str, threads: int) -> dict:
    """Redo the run's export with ``--hdr-format fmt``: its report (export wall time, hdr_video)."""
    for d in Path(run, "cache").glob("export-*"):
        shutil.rmtree(d)
    cmd = [sys.executable, "-m", "layercam", "hdr-video", *argv, "--out", str(run), "--hdr-format", fmt, "--quiet"]
    t0 = time.perf_counter()
    r = subprocess.run(cmd, env={**os.environ, "OMP_NUM_THREADS": str(threads)}, capture_output=True, text=True)
    if r.returncode:
        raise LayercamError(f"hdr-video --hdr-format {fmt} failed: {(r.stderr.strip().splitlines() or ['?'])[-1]}")
    rep = json.loads(Path(run, "report.json").read_text())
    return {"format": fmt, "export_s": rep["stages"]["export"]["seconds"],
            "command_s": round(time.perf_counter() - t0, 2),
            "hdr_video": rep["export"].get("hdr_video")}


def round_trip(run: Path, video: Path) -> dict:
    """hdr.mp4 (or an HLG one) back to radiance against the run's EXRs: median relative errors."""
    from layercam.core.bt2100 import eetf, primaries_matrix
    from layercam.io import read_exr
    from layercam.io.hdr_video import HdrMapping
    from layercam.io.hdr_video_read import read_hdr_video

    info = (json.loads((run / "report.json").read_text())["export"]["hdr_video"]
            if video.name == "hdr.mp4" else json.loads(video.with_suffix(".json").read_text()))
    exr = np.stack([read_exr(p) for p in sorted((run / "hdr").glob("frame_*.exr"))])
    light, probe = read_hdr_video(video)
    m = primaries_matrix(info["primaries_in"], "bt2020")
    mp = HdrMapping(info["format"], info["scale"], info["primaries_in"], info["source_peak"])
    if info["format"] == "hlg":  # back to scene light: the inverse OETF, not the display's OOTF
        from layercam.core.bt2100 import hlg_inverse_oetf

        light = hlg_inverse_oetf(probe["signal"]) * 1000.0
    back = light @ np.linalg.inv(m).T.astype(np.float32) / mp.scale
    lin = mp.light(exr).max(-1)
    y = np.array([0.2126, 0.7152, 0.0722], np.float32)
    ok = (exr @ y > info["white_radiance"] / 16) & np.isclose(eetf(lin, mp.source_peak), lin, rtol=1e-6)
    lum = np.abs(back @ y - exr @ y)[ok] / (exr @ y)[ok]
    rgb = np.abs(back - exr).sum(-1)[ok] / exr.sum(-1)[ok]
    return {"well_exposed_share": round(float(ok.mean()), 3),
            "median_lum_error": round(float(np.median(lum)), 4),
            "median_rgb_error": round(float(np.median(rgb)), 4),
            "p90_lum_error": round(float(np.percentile(lum, 90)), 4),
            "kbit_s": round(video.stat().st_size * 8 / (exr.shape[0] / float(probe["fps"] or 24))
                            / 1000, 1)}


def figure(run: Path, out: Path, frame: int) -> None:
    """preview.mp4's frame | hdr.mp4 (PQ) tone-mapped for SDR | an HLG hdr.mp4's signal as an SDR screen shows it."""
    import cv2

    from layercam.io import read_video
    from layercam.io.atomic import atomic_write
    from layercam.io.hdr_video_read import read_hdr_video, sdr_view

    previews = read_video(run / "preview.mp4")[0]
    frame = min(frame, len(previews) - 1)
    preview = previews[frame]
    pq, pinfo = read_hdr_video(run / "hdr.mp4")
    hlg_path = run / "render" / "hdr_hlg.mp4"
    subprocess.run([sys.executable, "-m", "layercam", "render", str(run), "--hdr-format", "hlg",
                    "--overwrite", "--quiet"], check=True)
    _, hinfo = read_hdr_video(hlg_path)
    panels = [preview.astype(np.float32) / 255,
              sdr_view(pq[frame], pinfo["content_light"]["max_cll"]),
              np.clip(hinfo["signal"][frame], 0, 1)]
    h, w = preview.shape[:2]
    gap = np.ones((h, 4, 3), np.float32)
    row = np.concatenate([panels[0], gap, panels[1], gap, panels[2]], 1)
    label = np.ones((18, row.shape[1], 3), np.float32)
    img = (np.concatenate([label, row], 0) * 255).round().astype(np.uint8)
    for i, text in enumerate(["preview.mp4 (SDR)", "hdr.mp4 PQ, tone-mapped for SDR", "HLG on an SDR screen"]):
        cv2.putText(img, text, (i * (w + 4) + 3, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.36, (0, 0, 0), 1, cv2.LINE_AA)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(out, lambda p: cv2.imwrite(str(p), img[..., ::-1]))


def table(rows: list[dict], formats: list[str], repeat: int) -> str:
    """The markdown table: per format the medians over the repeats, the last round trip."""
    lines = ["| hdr-format | export (s) | hdr.mp4 (s) | added | kbit/s | median luminance error | "
             "median RGB error |", "|---|---|---|---|---|---|---|"]
    base = np.median([r["export_s"] for r in rows if r["format"] == "none"]) if any(
        r["format"] == "none" for r in rows) else None
    for fmt in formats:
        rs = [r for r in rows if r["format"] == fmt]
        ex = np.median([r["export_s"] for r in rs])
        hv = np.median([r["hdr_video"]["seconds"] for r in rs]) if fmt != "none" else 0.0
        rt = rs[-1].get("round_trip") or {}
        added = f"+{hv / (ex - hv):.1%}" if fmt != "none" else ""
        lines.append(f"| {fmt} | {ex:.1f} | {hv:.1f} | {added} | {rt.get('kbit_s', '')} | "
                     f"{rt.get('median_lum_error', '')} | {rt.get('median_rgb_error', '')} |")
    if base is not None:
        lines.append(f"\nexport without hdr.mp4 (none): {base:.1f} s (median of {repeat})")
    return "\n".join(lines)


def run_hdr_video(out: Path, data: Path, preset: str = "balanced", formats: list[str] | None = None,
                  repeat: int = 2, overrides: list[str] | None = None,
                  quick: bool = False, force: bool = False, threads: int = 1, progress: bool = True) -> list[dict]:
    """The table: one row per export (``repeat`` x ``formats``); writes hdr_video.{json,md,png} under ``out``."""
    formats = formats or FORMATS
    bad = [f for f in formats if f not in FORMATS]
    if bad:
        raise LayercamError(f"--table hdr-video: unknown --variants {','.join(bad)} (hdr formats: {','.join(FORMATS)})")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    clip = quick_clip(out) if quick else Path(data) / CLIP
    if not clip.exists():
        raise LayercamError(f"missing shared capture {clip} (--data: the shared captures; see "
                            "../shared/data/README.md)")
    argv = [str(clip), "--exposures", "alt", "--ev-step", "3", "--preset",
            preset] + [a for s in (QUICK if quick else []) + list(overrides or [])
                       for a in ("--set", s)]
    run = out / "run"
    if force and run.exists():
        shutil.rmtree(run)
    rows = []
    for _ in range(repeat):
        for fmt in formats:
            r = _export(run, argv, fmt, threads)
            if fmt != "none":
                r["round_trip"] = round_trip(run, run / "hdr.mp4")
            rows.append(r)
            if progress:
                print(json.dumps(r), flush=True)
    if (json.loads((run / "report.json").read_text())["export"].get("hdr_video") or {}).get("format") != "pq":
        _export(run, argv, "pq", threads)
    figure(run, out / "hdr_video.png", FIGURE_FRAME)
    from layercam.io.atomic import atomic_write

    md = table(rows, formats, repeat)
    atomic_write(out / "hdr_video.json", lambda p: p.write_text(json.dumps(rows, indent=1)))
    atomic_write(out / "hdr_video.md", lambda p: p.write_text(md + "\n"))
    if progress:
        print(md)
    return rows
