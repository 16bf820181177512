"""``layercam edit``: paint on a layer's atlas, re-render the clip with the paint moving with the layer.

The atlas to paint on is the run's ``atlases/layer{k}.png`` (written by the atlas export): the layer
as the learned camera records it at the clip's reference exposure, on a grid over atlas ``uv`` in
``[-1, 1]^2``. Edit it (or paint on a transparent image of any size covering the same square) and
pass it back as RGBA. For every frame the edit is looked up where the frame's pixels map into that
layer, composited over the learned atlas, and the clip is re-rendered.

How the edit's colour becomes irradiance: it is read back through the inverse of the learned tone
mapper at the exposure the PNG was written at (``atlas.json``'s ``log2_dt_png``), so a colour
painted on the PNG appears as that colour in frames of that exposure, brighter or darker in the
others, and as the matching linear irradiance in the HDR frames. Values the camera cannot produce
(beyond 1/255 and 254/255 or past the curve's clipping points) are taken at the nearest it can.
Pixels of the edit that still equal the exported PNG (within 1.5/255) are left to the learned
atlas, so painting on the exported PNG changes only what was painted (and keeps its HDR detail).
Compositing is in linear irradiance: ``r = a * r_edit + (1 - a) * r_layer`` with the edit's alpha
``a``, then the layers composite as in the scene. The blur generator is not applied (sharp frames).

Outputs in ``RUN/edit/`` (or ``--out``): ``hdr/frame_00000.exr`` (linear), ``edited.mp4`` (each
frame through the learned camera at its own exposure), ``preview.mp4`` (HDR, display tonemapped)
and ``edit.json``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from layercam.cli import FPS, number
from layercam.errors import LayercamError

EXAMPLES = """examples:
  cp runs/clip/atlases/layer1.png edited.png        # paint on it in any image editor, keep RGBA
  layercam edit runs/clip --layer 1 --atlas edited.png
  layercam edit runs/clip --layer 0 --atlas logo.png --out runs/clip/edit_logo"""

UNCHANGED_TOL = 1.5 / 255


def register(sub) -> argparse.ArgumentParser:
    e = sub.add_parser(
        "edit",
        help="re-render a finished run with an edited (RGBA) atlas composited onto one layer",
        description="Composites an edited RGBA atlas image onto one layer's learned atlas and re-renders every frame: LDR through the learned camera and linear HDR.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    e.add_argument("run", help="a finished layercam run folder (holds checkpoint.pt and atlases/)")
    e.add_argument("--layer", type=number(int, 0), default=1, help="the layer whose atlas was edited: 0 background, 1 foreground (default 1)")
    e.add_argument("--atlas", required=True, help="the edited atlas, an RGBA PNG over the same uv square as atlases/layer{k}.png")
    e.add_argument("--out", help="output folder (default: RUN/edit)")
    e.add_argument("--overwrite", action="store_true", help="replace an earlier edit in the output folder")
    e.add_argument("--fps", type=FPS, help="video frame rate (default: the run's)")
    e.add_argument("--device", choices=["cpu", "cuda", "auto"], default="auto", help="auto (default: CUDA when present, else the CPU), cpu or cuda")
    e.add_argument("--quiet", action="store_true")
    return e


# -- functions used by the command and the tests ------------------------------------------------
def read_rgba(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """An image file -> ``rgb (h, w, 3)`` and ``alpha (h, w)`` float in [0, 1] (alpha 1 without one)."""
    import cv2

    p = Path(path)
    if not p.is_file():
        raise LayercamError(f"edited atlas not found: {p}")
    buf = np.fromfile(str(p), dtype=np.uint8)
    arr = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if buf.size else None
    if arr is None:
        raise LayercamError(f"cannot decode edited atlas {p} (use a PNG)")
    scale = 65535.0 if arr.dtype == np.uint16 else 255.0 if arr.dtype == np.uint8 else 1.0
    arr = arr.astype(np.float32) / scale
    if arr.ndim == 2:
        arr = arr[..., None]
    c = arr.shape[2]
    if c in (1, 2):
        rgb, alpha = np.repeat(arr[..., :1], 3, 2), (arr[..., 1] if c == 2 else np.ones(arr.shape[:2], np.float32))
    else:
        rgb, alpha = arr[..., 2::-1], (arr[..., 3] if c == 4 else np.ones(arr.shape[:2], np.float32))
    return np.ascontiguousarray(np.clip(rgb, 0, 1)), np.ascontiguousarray(np.clip(alpha, 0, 1))


def load_edit(model, run_dir: Path, layer: int, atlas_png: Path) -> dict:
    """The edit as a texture over the atlas square: ``{"irr": (h, w, 3) linear irradiance,
    "alpha": (h, w), "log2_dt": float, "unchanged_px": int}``."""
    from layercam.render import inverse_tone

    rgb, alpha = read_rgba(atlas_png)
    info_path = Path(run_dir) / "atlases" / "atlas.json"
    log2_dt = json.loads(info_path.read_text())["log2_dt_png"] if info_path.exists() else model.exposure.reference()
    unchanged = 0
    exported = Path(run_dir) / "atlases" / f"layer{layer}.png"
    if exported.exists() and exported.resolve() != Path(atlas_png).resolve():
        ref, _ = read_rgba(exported)
        if ref.shape == rgb.shape:
            same = np.abs(ref - rgb).max(-1) <= UNCHANGED_TOL
            unchanged = int(same.sum())
            alpha = np.where(same, 0.0, alpha).astype(np.float32)
    irr = np.exp2(inverse_tone(model, rgb, log2_dt)).astype(np.float32)
    return {"irr": irr, "alpha": alpha, "log2_dt": float(log2_dt), "unchanged_px": unchanged}


def sample_edit(edit: dict, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Look the edit up at atlas coordinates ``uv (H, W, 2)`` (bilinear, premultiplied alpha; nothing
    outside the atlas square) -> ``irr (H, W, 3)``, ``alpha (H, W)``."""
    import torch
    import torch.nn.functional as F

    tex = np.concatenate([edit["irr"] * edit["alpha"][..., None], edit["alpha"][..., None]], -1)
    t = torch.from_numpy(np.ascontiguousarray(tex)).permute(2, 0, 1)[None]
    g = torch.from_numpy(np.ascontiguousarray(uv, dtype=np.float32))[None]
    s = F.grid_sample(t, g, mode="bilinear", padding_mode="zeros", align_corners=False)[0].permute(1, 2, 0).numpy()
    a = s[..., 3]
    irr = s[..., :3] / np.maximum(a, 1e-8)[..., None]
    return irr, np.clip(a, 0, 1)


def render_edited_frame(model, t: int, hw: tuple[int, int], layer: int, edit: dict, chunk: int = 65536) -> dict:
    """Frame ``t`` with the edit on ``layer``: ``{"hdr": (H, W, 3) linear, "ldr": (H, W, 3) in [0, 1]
    through the camera at the frame's exposure, "edit_alpha": (H, W) how much of the edit shows}``."""
    from layercam.render import composite_layers, layer_weights, render_frame, tone_map_log2

    out = render_frame(model, t, hw, ("layers", "uv", "alpha"), chunk=chunk)
    layers = [np.exp2(lg) for lg in out["layers"]]
    irr, a = sample_edit(edit, out["uv"][layer])
    layers[layer] = a[..., None] * irr + (1 - a[..., None]) * layers[layer]
    hdr = composite_layers(layers, out["alpha"]).astype(np.float32)
    log2_dt = float(model.exposure.values().detach().cpu()[t])
    ldr = tone_map_log2(model, np.log2(np.maximum(hdr, 1e-30)), log2_dt)
    seen = a * layer_weights(out["alpha"], len(layers), hw)[layer]
    return {"hdr": hdr, "ldr": ldr, "edit_alpha": seen.astype(np.float32)}


EDIT_OUTPUTS = ["hdr", "edited.mp4", "preview.mp4", "edit.json"]  # edit.json last: marks a finished edit


def run(args) -> int:
    import contextlib

    from layercam.io.atomic import partials_removed_on_error
    from layercam.io.lock import run_lock

    run_dir = Path(args.run)
    with run_lock(run_dir) if (run_dir / "checkpoint.pt").is_file() else contextlib.nullcontext():  # one writer per run folder
        with partials_removed_on_error(_out_dir(args, run_dir)):
            return _edit(args, run_dir)


def _out_dir(args, run_dir: Path) -> Path:
    return Path(args.out) if args.out else run_dir / "edit"


def _say_faded(run_dir: Path) -> None:
    """Repeats the run's warning that its foreground faded in training (``report.json``): an edit
    of that layer shows only where alpha is left."""
    import sys

    from layercam.pipelines.tasks import FADED

    try:
        warnings = json.loads((run_dir / "report.json").read_text()).get("warnings") or []
    except (OSError, ValueError, AttributeError):
        return
    for w in warnings:
        if isinstance(w, str) and w.startswith(FADED):
            print(f"warning: {w}", file=sys.stderr, flush=True)


def _edit(args, run_dir: Path) -> int:
    from layercam.checkpoint import load_run_model
    from layercam.interrupts import reached
    from layercam.io import write_exr, write_video
    from layercam.io.atomic import commit_staged, ensure_writable_dir, staging_dir
    from layercam.pipelines.runner import write_json
    from layercam.pipelines.stages import device_of
    from layercam.progress import bar as progress_bar
    from layercam.render import tonemap_display

    model, meta = load_run_model(run_dir, device_of(args.device))
    L = model.scene.n_layers
    if not 0 <= args.layer < L:
        raise LayercamError(f"--layer {args.layer}: this run has {L} layer{'s' if L > 1 else ''} (0{'' if L == 1 else f'..{L - 1}'})")
    if args.layer > 0:
        _say_faded(run_dir)
    out = _out_dir(args, run_dir)
    if (out / "edit.json").exists() and not args.overwrite:
        raise LayercamError(f"{out} already holds an edit; pass --overwrite or choose another --out")
    edit = load_edit(model, run_dir, args.layer, Path(args.atlas))
    if not (edit["alpha"] > 0).any():
        raise LayercamError(f"{args.atlas}: nothing to composite (fully transparent, or identical to the exported atlas)")
    ensure_writable_dir(out)  # before any frame is rendered
    stage = staging_dir(out, "edit")
    (stage / "hdr").mkdir()
    hw = tuple(meta["frame_hw"])
    T = int(meta["n_frames"])
    hdrs, ldrs, cover = [], [], []
    for t in progress_bar(range(T), desc="edit", unit="frame", enabled=not args.quiet):
        reached("edit", t)
        r = render_edited_frame(model, t, hw, args.layer, edit)
        if not np.isfinite(r["hdr"]).all():
            raise LayercamError(f"frame {t}: non-finite irradiance after the edit; nothing written for it")
        write_exr(stage / "hdr" / f"frame_{t:05d}.exr", r["hdr"])
        hdrs.append(r["hdr"])
        ldrs.append(r["ldr"])
        cover.append(float((r["edit_alpha"] > 0.5).mean()))
    fps = args.fps or float(meta.get("fps") or 24.0)
    write_video(stage / "edited.mp4", np.stack(ldrs), fps=fps)
    write_video(stage / "preview.mp4", tonemap_display(np.stack(hdrs))[0], fps=fps)
    write_json(stage / "edit.json", {
        "run": str(run_dir), "layer": args.layer, "atlas": str(Path(args.atlas).resolve()),
        "log2_dt_png": edit["log2_dt"], "unchanged_px_left_to_learned_atlas": edit["unchanged_px"],
        "frames": T, "edit_visible_fraction_per_frame": cover,
        "outputs": {"hdr": "hdr/frame_*.exr (linear)", "edited.mp4": "through the learned camera at each frame's exposure", "preview.mp4": "HDR, display tonemapped"},
    })
    commit_staged(stage, out, EDIT_OUTPUTS)
    if not args.quiet:
        print(f"done: {out}  (edit visible in {sum(c > 0 for c in cover)} of {T} frames)")
    return 0
