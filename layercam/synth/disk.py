"""A synthetic alternating-exposure clip written to disk one frame at a time, with its ground truth,
for clips too large to hold in memory (1920x1080 x 48 frames is 1.2 GB of float32 frames and as
much ground truth): ``frames/frame_00000.png`` (8-bit, what a user would pass), ``truth/frame_00000.exr``
(linear irradiance, float32), ``times.txt`` (one exposure time per frame, for ``--exposures``) and
``scene.json``. Frame for frame the same as :func:`layercam.synth.pan_hdr` with the same arguments.

    python -m layercam.synth.disk OUT --size 1080x1920 --frames 48
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def write_pan_hdr(out: Path, frames: int = 48, size: tuple[int, int] = (1080, 1920),
                  ev_step: float = 3.0, seed: int = 0, progress: bool = False) -> dict:
    """Writes the clip into ``out`` (skipped when ``scene.json`` there already describes it) and
    returns what ``scene.json`` holds. ``size`` is ``(H, W)``. Peak memory: the canvas and a frame."""
    from layercam import synth
    from layercam.io import write_exr, write_png
    from layercam.io.atomic import atomic_write, ensure_writable_dir
    from layercam.core.progress import bar

    out = ensure_writable_dir(Path(out))
    want = {"family": "pan_hdr", "frames": int(frames), "size": [int(size[0]), int(size[1])],
            "ev_step": float(ev_step), "seed": int(seed)}
    done = out / "scene.json"
    if done.exists() and json.loads(done.read_text()).get("args") == want:
        return json.loads(done.read_text())
    meta, times, each = synth.pan_hdr_frames(frames, size, ev_step, seed=seed)
    (out / "frames").mkdir(exist_ok=True)
    (out / "truth").mkdir(exist_ok=True)
    for t, (hdr, ldr) in enumerate(bar(each, total=frames, desc="synth", unit="frame", enabled=progress)):
        write_png(out / "frames" / f"frame_{t:05d}.png", ldr)
        write_exr(out / "truth" / f"frame_{t:05d}.exr", hdr, half=False)
    atomic_write(out / "times.txt",
                 lambda p: p.write_text("".join(f"frame_{t:05d} {v:g}\n" for t,
                                                v in enumerate(times))))
    info = {"args": want, "gain": meta["gain"], "crf": "srgb", "exposure_times": [float(v) for v in times],
            "frames": "frames/frame_*.png", "truth": "truth/frame_*.exr (linear, float32)"}
    atomic_write(done, lambda p: p.write_text(json.dumps(info, indent=1)))
    return info


def truth_frame(out: Path, t: int) -> np.ndarray:
    """Ground-truth irradiance of frame ``t`` ``(H, W, 3)`` of a clip written by :func:`write_pan_hdr`."""
    from layercam.io import read_exr

    return read_exr(Path(out) / "truth" / f"frame_{t:05d}.exr")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m layercam.synth.disk",
                                description="Write a synthetic pan_hdr clip with ground truth to "
                                            "disk, frame by frame.")
    p.add_argument("out")
    p.add_argument("--size", default="1080x1920", help="HxW (default 1080x1920)")
    p.add_argument("--frames", type=int, default=48)
    p.add_argument("--ev-step", type=float, default=3.0)
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args(argv)
    h, w = (int(v) for v in a.size.lower().split("x"))
    info = write_pan_hdr(Path(a.out), a.frames, (h, w), a.ev_step, a.seed, progress=True)
    print(f"wrote {a.out}: {a.frames} frames {w}x{h}, times.txt, truth/ (gain {info['gain']:.4g})")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
