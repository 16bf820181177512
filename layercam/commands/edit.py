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

A long clip's run (``windows.json``: windows of frames, each its own model with its own atlases in
``RUN/windows/wK/atlases/``): paint on one window's atlas and name it with ``--window K``. The edit
is carried to the other windows through the frames neighbouring windows share: each pixel of an
overlap frame looks the edit up where it maps into the painted window's atlas and leaves it where
it maps into the neighbour's (:func:`carry_edit`), window after window outwards; so every window
shows the edit where its frames see what the overlaps saw of it (what only frames far from an
overlap see of the painted window's atlas stays in that window). The frames are then joined across
the overlaps as the run's export joined them.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from layercam.cli import FPS, number
from layercam.core.errors import LayercamError

EXAMPLES = """examples:
  cp runs/clip/atlases/layer1.png edited.png        # paint on it in any image editor, keep RGBA
  layercam edit runs/clip --layer 1 --atlas edited.png
  layercam edit runs/clip --layer 0 --atlas logo.png --out runs/clip/edit_logo
  layercam edit runs/long --layer 0 --window 2 --atlas wall.png   # a long clip: paint on windows/w02/atlases/layer0.png

a long clip's run (windows/, windows.json): each window is its own model with its own atlases.
Paint on one window's atlas and name it with --window K: the edit shows in that window's frames and
is carried to every other window through the frames neighbouring windows share (each overlap
frame's pixels look it up where they map into one window's atlas and leave it where they map into
the next's), so it follows the scene through the whole clip wherever the overlaps saw it; what
only frames far from every overlap see stays in the painted window (cross-faded out at its ends)."""

UNCHANGED_TOL = 1.5 / 255


def register(sub) -> argparse.ArgumentParser:
    e = sub.add_parser(
        "edit",
        help="re-render a finished run with an edited (RGBA) atlas composited onto one layer",
        description="Composites an edited RGBA atlas image onto one layer's learned atlas and "
                    "re-renders every frame: LDR through the learned camera and linear HDR.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    e.add_argument("run", help="a finished layercam run folder (holds checkpoint.pt and atlases/)")
    e.add_argument("--layer", type=number(int, 0), default=1,
                   help="the layer whose atlas was edited: 0 background, 1 foreground (default 1)")
    e.add_argument("--atlas", required=True,
                   help="the edited atlas, an RGBA PNG over the same uv square as "
                        "atlases/layer{k}.png")
    e.add_argument("--window", type=number(int, 0), metavar="K",
                   help="a long clip's run (windows/): the window whose atlas you painted on, "
                        "windows/wK/atlases/layer{k}.png; carried to the other windows through the "
                        "frames they share")
    e.add_argument("--out", help="output folder (default: RUN/edit)")
    e.add_argument("--overwrite", action="store_true", help="replace an earlier edit in the output folder")
    e.add_argument("--fps", type=FPS, help="video frame rate (default: the run's)")
    e.add_argument("--device", choices=["cpu", "cuda", "auto"], default="auto",
                   help="auto (default: CUDA when present, else the CPU), cpu or cuda")
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
    from layercam.scene.render import inverse_tone

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
    from layercam.scene.render import composite_layers, layer_weights, render_frame, tone_map_log2

    out = render_frame(model, t, hw, ("layers", "uv", "alpha"), chunk=chunk)
    layers = [np.exp2(lg) for lg in out["layers"]]
    irr, a = sample_edit(edit, out["uv"][layer])
    layers[layer] = a[..., None] * irr + (1 - a[..., None]) * layers[layer]
    hdr = composite_layers(layers, out["alpha"]).astype(np.float32)
    log2_dt = float(model.exposure.values().detach().cpu()[t])
    ldr = tone_map_log2(model, np.log2(np.maximum(hdr, 1e-30)), log2_dt)
    seen = a * layer_weights(out["alpha"], len(layers), hw)[layer]
    return {"hdr": hdr, "ldr": ldr, "edit_alpha": seen.astype(np.float32)}


def carry_edit(edit: dict, src, dst, pairs: list[tuple[int, int]], hw: tuple[int, int], layer: int,
               res: tuple[int, int]) -> dict:
    """An edit on ``src``'s atlas of ``layer`` carried to ``dst``'s (two windows' models) through
    frames both render: ``pairs`` of the same frame's index in each. Every pixel where the layer is
    seen in both looks the edit up at its ``src`` atlas coordinates (:func:`sample_edit`) and leaves
    it, bilinearly, at its ``dst`` ones, on a ``res = (h, w)`` texture; per texel the edit's
    irradiance (weighted by its alpha) and alpha (the mean over the pixels that landed there); a
    texel no pixel reached between reached ones takes its 3x3 neighbours'. Returns an edit as
    :func:`load_edit` does."""
    import cv2

    from layercam.scene.render import layer_weights, render_frame

    h, w = res
    acc = np.zeros((h * w, 5), np.float64)  # irr * a * seen (3), a * seen, seen
    L = src.scene.n_layers
    for i_s, i_d in pairs:
        o_s = render_frame(src, i_s, hw, ("uv", "alpha"))
        o_d = render_frame(dst, i_d, hw, ("uv", "alpha"))
        seen = layer_weights(o_s["alpha"], L, hw)[layer] * layer_weights(o_d["alpha"], L, hw)[layer]
        irr, a = sample_edit(edit, o_s["uv"][layer])
        vals = np.concatenate([irr * (a * seen)[..., None], (a * seen)[..., None], seen[..., None]], -1).reshape(-1, 5)
        uv = o_d["uv"][layer].reshape(-1, 2)
        x, y = (uv[:, 0] + 1) / 2 * w - 0.5, (uv[:, 1] + 1) / 2 * h - 0.5
        x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
        fx, fy = x - x0, y - y0
        for dx, dy, wt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
            cx, cy = x0 + dx, y0 + dy
            ok = (cx >= 0) & (cx < w) & (cy >= 0) & (cy < h) & (wt > 0)
            np.add.at(acc, cy[ok] * w + cx[ok], vals[ok] * wt[ok, None])
    acc = acc.reshape(h, w, 5).astype(np.float32)
    hole = acc[..., 4] <= 1e-6
    near = cv2.blur(acc, (3, 3), borderType=cv2.BORDER_CONSTANT)
    acc[hole] = near[hole]
    a_sum, seen = acc[..., 3], acc[..., 4]
    alpha = np.where(seen > 1e-6, a_sum / np.maximum(seen, 1e-6), 0.0).astype(np.float32)
    irr = np.where((a_sum > 1e-6)[..., None], acc[..., :3] / np.maximum(a_sum, 1e-6)[..., None], 0.0).astype(np.float32)
    return {"irr": irr, "alpha": np.clip(alpha, 0.0, 1.0), "log2_dt": edit["log2_dt"], "unchanged_px": 0}


EDIT_OUTPUTS = ["hdr", "edited.mp4", "preview.mp4", "edit.json"]  # edit.json last: marks a finished edit


def run(args) -> int:
    import contextlib

    from layercam.io.atomic import partials_removed_on_error
    from layercam.io.lock import run_lock
    from layercam.pipelines.windows.index import INDEX

    run_dir = Path(args.run)
    finished = (run_dir / "checkpoint.pt").is_file() or (run_dir / INDEX).is_file()
    with run_lock(run_dir) if finished else contextlib.nullcontext():  # one writer per run folder
        with partials_removed_on_error(_out_dir(args, run_dir)):
            return _edit(args, run_dir)


def _out_dir(args, run_dir: Path) -> Path:
    return Path(args.out) if args.out else run_dir / "edit"


def _edit_target(args, run_dir: Path, L: int) -> Path:
    """The edit's output folder, after checking ``--layer`` against the run's ``L`` layers and that
    the folder holds no edit (unless ``--overwrite``)."""
    if not 0 <= args.layer < L:
        raise LayercamError(f"--layer {args.layer}: this run has {L} layer{'s' if L > 1 else ''} "
                            f"(0{'' if L == 1 else f'..{L - 1}'})")
    if args.layer > 0:
        _say_faded(run_dir)
    out = _out_dir(args, run_dir)
    if (out / "edit.json").exists() and not args.overwrite:
        raise LayercamError(f"{out} already holds an edit; pass --overwrite or choose another --out")
    return out


def _say_faded(run_dir: Path) -> None:
    """Repeats the run's warning that its foreground faded in training (``report.json``): an edit
    of that layer shows only where alpha is left."""
    import sys

    from layercam.pipelines.stages import FADED

    try:
        warnings = json.loads((run_dir / "report.json").read_text()).get("warnings") or []
    except (OSError, ValueError, AttributeError):
        return
    for w in warnings:
        if isinstance(w, str) and w.startswith(FADED):
            print(f"warning: {w}", file=sys.stderr, flush=True)


def _edit(args, run_dir: Path) -> int:
    from layercam.engine.checkpoint import load_run_model
    from layercam.core.interrupts import reached
    from layercam.io import write_exr, write_video
    from layercam.io.atomic import commit_staged, ensure_writable_dir, staging_dir
    from layercam.pipelines.runner import write_json
    from layercam.engine.resolve import device_of
    from layercam.core.progress import bar as progress_bar
    from layercam.scene.render import tonemap_display

    from layercam.pipelines.windows import index as windows

    index = windows.read_index(run_dir)
    if index is not None:
        return _edit_windows(args, run_dir, index)
    if args.window is not None:
        raise LayercamError(f"--window {args.window}: {run_dir} is one model, not a long clip's "
                            "windows; leave --window out")
    model, meta = load_run_model(run_dir, device_of(args.device))
    L = model.scene.n_layers
    out = _edit_target(args, run_dir, L)
    edit = load_edit(model, run_dir, args.layer, Path(args.atlas))
    if not (edit["alpha"] > 0).any():
        raise LayercamError(f"{args.atlas}: nothing to composite (fully transparent, or identical "
                            "to the exported atlas)")
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
    from layercam.commands.render import run_audio

    fps = args.fps or float(meta.get("fps") or 24.0)
    write_video(stage / "edited.mp4", np.stack(ldrs), fps=fps, audio=run_audio(meta, fps))
    write_video(stage / "preview.mp4", tonemap_display(np.stack(hdrs))[0], fps=fps, audio=run_audio(meta, fps))
    write_json(stage / "edit.json", {
        "run": str(run_dir), "layer": args.layer, "atlas": str(Path(args.atlas).resolve()),
        "log2_dt_png": edit["log2_dt"], "unchanged_px_left_to_learned_atlas": edit["unchanged_px"],
        "frames": T, "edit_visible_fraction_per_frame": cover,
        "outputs": {"hdr": "hdr/frame_*.exr (linear)",
                    "edited.mp4": "through the learned camera at each frame's exposure",
                    "preview.mp4": "HDR, display tonemapped"},
    })
    commit_staged(stage, out, EDIT_OUTPUTS)
    if not args.quiet:
        print(f"done: {out}  (edit visible in {sum(c > 0 for c in cover)} of {T} frames)")
    return 0


def _edit_windows(args, run_dir: Path, index: dict) -> int:
    """``layercam edit`` on a long clip's windows (this module's docstring)."""
    from layercam.engine.checkpoint import load_run_model
    from layercam.core.interrupts import reached
    from layercam.io import write_exr, write_video
    from layercam.io.atomic import commit_staged, ensure_writable_dir, staging_dir
    from layercam.pipelines.windows import index as windows
    from layercam.pipelines.windows.plan import per_pixel
    from layercam.pipelines.runner import write_json
    from layercam.engine.resolve import device_of
    from layercam.core.progress import bar as progress_bar
    from layercam.scene.render import tonemap_display

    plan, folders = windows.index_plan(index, run_dir), windows.window_folders(run_dir, index)
    n = plan.count
    if args.window is None:
        raise LayercamError(f"{run_dir} holds a long clip as {n} windows, each with its own "
                            "atlases: say which window's atlas you painted on with "
                            f"--window K (0..{n - 1}; window K's is "
                            f"{folders[0].relative_to(run_dir).parent}/wK/atlases/layer{args.layer}.png)")
    K = args.window
    if not 0 <= K < n:
        raise LayercamError(f"--window {K}: this run has {n} windows (0..{n - 1})")
    dev = device_of(args.device)
    loaded = [load_run_model(f, dev) for f in folders]
    models, metas = [m for m, _ in loaded], [m for _, m in loaded]
    L = models[0].scene.n_layers
    out = _edit_target(args, run_dir, L)
    hw = tuple(metas[0]["frame_hw"])
    gains = windows.index_gains(index)  # each window's irradiance against window 0's (1 where the camera is shared)
    edits: list = [None] * n
    edits[K] = load_edit(models[K], folders[K], args.layer, Path(args.atlas))
    if not (edits[K]["alpha"] > 0).any():
        raise LayercamError(f"{args.atlas}: nothing to composite (fully transparent, or identical "
                            f"to window {K}'s exported atlas)")
    ensure_writable_dir(out)  # before any frame is rendered
    how = {K: "painted"}
    for j in [*range(K + 1, n), *range(K - 1, -1, -1)]:
        i = j - 1 if j > K else j + 1  # the neighbour it is carried from
        a, b = max(plan.windows[i][0], plan.windows[j][0]), min(plan.windows[i][1], plan.windows[j][1])
        png = folders[j] / "atlases" / f"layer{args.layer}.png"
        res = read_rgba(png)[1].shape if png.exists() else edits[i]["alpha"].shape
        edits[j] = carry_edit(edits[i], models[i], models[j],
                              [(t - plan.windows[i][0], t - plan.windows[j][0])
                               for t in range(a, b)], hw, args.layer, res)
        edits[j]["irr"] = edits[j]["irr"] * np.float32(gains[j] / gains[i])  # in window j's irradiance
        how[j] = f"carried from window {i} through frames {a}..{b - 1}"
    stage = staging_dir(out, "edit")
    (stage / "hdr").mkdir()
    T = int(index["frames"])
    hdrs, ldrs, cover = [], [], []
    for t in progress_bar(range(T), desc="edit", unit="frame", enabled=not args.quiet):
        reached("edit", t)
        ws = plan.weights(t, hw)  # as the export joined them: per pixel where the run kept the windows' fits
        parts = [(w, render_edited_frame(models[k], t - plan.windows[k][0], hw, args.layer, edits[k])) for k, w in ws]
        r = {key: sum(per_pixel(w, p[key]) * p[key] for w, p in parts).astype(np.float32)
             for key in ("ldr", "edit_alpha")}
        r["hdr"] = sum(per_pixel(w * gains[k], p["hdr"]) * p["hdr"] for (k, _),
                       (w, p) in zip(ws, parts)).astype(np.float32)
        if not np.isfinite(r["hdr"]).all():
            raise LayercamError(f"frame {t}: non-finite irradiance after the edit; nothing written for it")
        write_exr(stage / "hdr" / f"frame_{t:05d}.exr", r["hdr"])
        hdrs.append(r["hdr"])
        ldrs.append(r["ldr"])
        cover.append(float((r["edit_alpha"] > 0.5).mean()))
    fps = args.fps or float(metas[0].get("fps") or 24.0)
    write_video(stage / "edited.mp4", np.stack(ldrs), fps=fps)
    write_video(stage / "preview.mp4", tonemap_display(np.stack(hdrs))[0], fps=fps)
    write_json(stage / "edit.json", {
        "run": str(run_dir), "layer": args.layer, "atlas": str(Path(args.atlas).resolve()), "window": K,
        "windows": [{"frames": list(plan.windows[k]), "edit": how[k],
                     "edit_alpha_sum": float(edits[k]["alpha"].sum())} for k in range(n)],
        "log2_dt_png": edits[K]["log2_dt"], "unchanged_px_left_to_learned_atlas": edits[K]["unchanged_px"],
        "frames": T, "edit_visible_fraction_per_frame": cover,
        "outputs": {"hdr": "hdr/frame_*.exr (linear)",
                    "edited.mp4": "through the learned camera at each frame's exposure",
                    "preview.mp4": "HDR, display tonemapped"},
    })
    commit_staged(stage, out, EDIT_OUTPUTS)
    if not args.quiet:
        print(f"done: {out}  (edit visible in {sum(c > 0 for c in cover)} of {T} frames; painted "
              f"on window {K}, carried to the others through their overlaps)")
    return 0
