"""The flow stage's arrays, computed a pair at a time and kept on disk.

In the stage's folder: ``fw.raw``, ``bw.raw`` (``(T-1, h, w, 2)`` float16 flows, pixels of the
working grid ``h x w``, :func:`layercam.vision.scale.working_size`), ``fw_ok.raw``, ``bw_ok.raw``
(forward-backward consistency) and ``vis.raw`` (both frames see the pixel well), each ``(T-1, h, w)``
bool, all :class:`~layercam.io.frames.DiskArray`; ``homs.npy`` ``(T-1, 3, 3)`` float64 (the global
homography of each pair, fitted to the float32 flow where it is consistent and seen well) and
``flow.json`` (shapes and dtypes). :func:`load` opens them as the dict the stages read
(``ctx.flow``): the arrays index like ndarrays (``fl["fw"][t]`` reads one pair) and the sampler
gathers pixels from them; nothing holds the clip's flow in memory.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from layercam.core.interrupts import reached
from layercam.io.frames import DiskArray

ARRAYS = {"fw": (np.float16, 2), "bw": (np.float16, 2), "fw_ok": (np.bool_, 0), "bw_ok": (np.bool_, 0), "vis": (np.bool_, 0)}



def compute(frames, out: Path, cfg, progress: bool = False) -> dict:
    """Flow of the clip ``frames`` (``(T,H,W,3)``, read a frame at a time) with the ``flow``
    settings ``cfg`` into ``out``; returns the stage's summary. Pair for pair the arrays the
    whole-clip functions give (``flow.compute_flow``, ``flow.pair_arrays``): the same DIS object
    over the pairs, OpenCV's RNG seeded once for the homographies."""
    import cv2

    from layercam.vision import flow, raft, scale
    from layercam.core.progress import bar
    from layercam.core.visibility import visible

    out = Path(out)
    T, H, W = frames.shape[:3]
    n = max(T - 1, 0)
    work = scale.working_size((H, W))
    h, w = work
    arrays = {k: DiskArray.create(out / f"{k}.raw", dt, (n, h, w, 2) if c else (n, h, w)) for k, (dt, c) in ARRAYS.items()}
    homs = np.repeat(np.eye(3)[None], n, 0)
    last2: list = []  # the pair's two frames, as the flow read them

    def feed():
        small = scale.ResizedFrames(frames, work)
        for t in range(len(small)):
            f = small[t]
            last2[:] = last2[-1:] + [f]
            yield f

    if cfg.method.startswith("raft"):
        model = raft.raft_model(cfg.raft_weights, None if cfg.method == "raft" else cfg.method[5:])
        pairs = raft.raft_pairs(feed(), model)
    else:
        pairs = flow.dis_pairs(feed(), cfg.method)
    mag_sum, ok_sum = 0.0, 0
    px = W / w  # working-grid pixels in frame pixels
    cv2.setRNGSeed(0)  # once, as global_homographies seeds it for all pairs
    vis_next = None
    for i, (fw, bw) in enumerate(bar(pairs, total=n, desc=f"flow ({cfg.method})", unit="pair", enabled=progress)):
        reached("flow", i)
        cur, nxt = last2
        fw_ok = flow.flow_consistency(fw[None], bw[None])[0]
        bw_ok = flow.flow_consistency(bw[None], fw[None])[0]
        vis_cur = visible(cur) if vis_next is None else vis_next
        vis_next = visible(nxt)
        vis = vis_cur & (flow.warp(vis_next.astype(np.float32), fw) > 0.5)  # visibility.pair_visible, one pair
        homs[i] = flow.pair_homography(fw, vis & fw_ok)
        for k, v in (("fw", fw), ("bw", bw), ("fw_ok", fw_ok), ("bw_ok", bw_ok), ("vis", vis)):
            arrays[k][i] = v
        mag_sum += float(np.sqrt((fw**2).sum(-1)).sum(dtype=np.float64)) * px
        ok_sum += int(fw_ok.sum())
    for a in arrays.values():
        a.flush()
        a.close()
    np.save(out / "homs.npy", homs.astype(np.float64))
    (out / "flow.json").write_text(json.dumps({"pairs": n, "working_size": [h, w], "arrays": {k: [np.dtype(dt).str, c] for k, (dt, c) in ARRAYS.items()}}))
    if n == 0:
        return {"pairs": 0}
    px = n * h * w
    return {"pairs": n, "working_size": [h, w], "mean_flow_px": mag_sum / px, "consistent_fraction": ok_sum / px}


def load(out: Path) -> dict | None:
    """The arrays :func:`compute` left in ``out`` (opened, not read), or None for a single frame. A
    flow cached before (one ``flow.npz``) is moved to this layout first, an array at a time."""
    out = Path(out)
    if not (out / "flow.json").exists() and (out / "flow.npz").exists():
        _migrate(out)
    info = json.loads((out / "flow.json").read_text())
    n = info["pairs"]
    if not n:
        return None
    h, w = info["working_size"]
    fl = {k: DiskArray(out / f"{k}.raw", dt, (n, h, w, 2) if c else (n, h, w)) for k, (dt, c) in info["arrays"].items()}
    fl["homs"] = np.load(out / "homs.npy")
    return fl


def _migrate(out: Path) -> None:
    """``flow.npz`` (the flow stage's cache before it was kept a file per array) as :func:`compute`
    leaves it: the same arrays, so the stages after it keep their caches."""
    with np.load(out / "flow.npz") as z:
        n = len(z["fw"])
        h, w = z["fw"].shape[1:3] if n else (0, 0)
        for k, (dt, c) in ARRAYS.items():
            if k in z.files or n == 0:
                a = DiskArray.create(out / f"{k}.raw", dt, (n, h, w, 2) if c else (n, h, w))
                if n:
                    a[0:n] = z[k]
                a.close()
        np.save(out / "homs.npy", z["homs"].astype(np.float64) if "homs" in z.files else np.repeat(np.eye(3)[None], n, 0))
    (out / "flow.json").write_text(json.dumps({"pairs": n, "working_size": [int(h), int(w)], "arrays": {k: [np.dtype(dt).str, c] for k, (dt, c) in ARRAYS.items()}}))
