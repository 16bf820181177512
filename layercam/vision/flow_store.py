"""The flow stage's arrays, computed a pair at a time and kept on disk.

In the stage's folder: ``fw.raw``, ``bw.raw`` (``(T-1, h, w, 2)`` float16 flows, pixels of the
working grid ``h x w``, :func:`layercam.vision.scale.working_size`), ``fw_ok.raw``, ``bw_ok.raw``
(forward-backward consistency) and ``vis.raw`` (both frames see the pixel well), each ``(T-1, h, w)``
bool, all :class:`~layercam.io.frames.DiskArray`; ``homs.npy`` ``(T-1, 3, 3)`` float64 (the global
homography of each pair, fitted to the float32 flow where it is consistent and seen well) and
``flow.json`` (shapes and dtypes). :func:`load` opens them as the :class:`FlowArrays` the stages
read (``ctx.flow``): the arrays index like ndarrays (``fl.fw[t]`` reads one pair) and the sampler
gathers pixels from them; nothing holds the clip's flow in memory.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from layercam.core.interrupts import reached
from layercam.io.frames import DiskArray
from layercam.vision import scale

ARRAYS = {"fw": (np.float16, 2), "bw": (np.float16, 2), "fw_ok": (np.bool_, 0),
          "bw_ok": (np.bool_, 0), "vis": (np.bool_, 0)}


@dataclass(frozen=True, eq=False)
class FlowArrays(Mapping):
    """The flow of a clip's ``N = T - 1`` neighbour pairs on a working grid ``h x w``: ``fw``, ``bw``
    ``(N, h, w, 2)`` flows (pixels of that grid), ``fw_ok``, ``bw_ok`` ``(N, h, w)`` forward-backward
    consistency, ``vis`` ``(N, h, w)`` both frames see the pixel well, ``homs`` ``(N, 3, 3)`` each
    pair's global homography. The arrays are anything that indexes like an ndarray (the flow
    stage's :class:`~layercam.io.frames.DiskArray`, or arrays in memory); a field may be None where a
    reader left it out (:func:`at_frame_size`'s ``keys``).

    Also a read-only mapping of the arrays present (``fl["fw"]``), the contract of the vision
    functions that take any mapping of flows (``layercam.vision.flow.compute_flow``'s dict)."""

    fw: Any = None
    bw: Any = None
    fw_ok: Any = None
    bw_ok: Any = None
    vis: Any = None
    homs: Any = None

    @classmethod
    def of(cls, arrays: Mapping) -> "FlowArrays":
        """From any mapping of these names (others are not flow arrays: a KeyError says so)."""
        bad = set(arrays) - {f.name for f in fields(cls)}
        if bad:
            raise KeyError(f"not flow arrays: {sorted(bad)}")
        return cls(**arrays)

    @property
    def pairs(self) -> int:
        return len(self.fw) if self.fw is not None else len(self.homs)

    @property
    def grid(self) -> tuple[int, int]:
        """``(h, w)``: the working grid the flows are on."""
        return tuple(self.fw.shape[1:3])

    def rows(self, a: int, b: int) -> "FlowArrays":
        """Pairs ``a .. b - 1`` (views of arrays on disk: nothing read)."""
        return replace(self,
                       **{k: (v.rows(a, b) if hasattr(v, "rows") else np.asarray(v)[a:b]) for k,
                          v in self.items()})

    def __getitem__(self, k: str):
        v = getattr(self, k, None) if k in _NAMES else None
        if v is None:
            raise KeyError(k)
        return v

    def __iter__(self):
        return (k for k in _NAMES if getattr(self, k) is not None)

    def __len__(self) -> int:
        return sum(1 for _ in self)


_NAMES = tuple(f.name for f in fields(FlowArrays))



def compute(frames, out: Path, cfg, progress: bool = False, device: str = "cpu") -> dict:
    """Flow of the clip ``frames`` (``(T,H,W,3)``, read a frame at a time) with the ``flow``
    settings ``cfg`` into ``out`` (RAFT on ``device``); returns the stage's summary. Pair for pair the arrays the
    whole-clip functions give (``flow.compute_flow``, ``flow.pair_arrays``): the same DIS object
    over the pairs, OpenCV's RNG seeded once for the homographies."""
    import cv2

    from layercam.vision import flow, raft
    from layercam.core.progress import bar
    from layercam.core.visibility import visible

    out = Path(out)
    T, H, W = frames.shape[:3]
    n = max(T - 1, 0)
    work = scale.working_size((H, W))
    h, w = work
    arrays = {k: DiskArray.create(out / f"{k}.raw", dt, (n, h, w, 2) if c else (n, h, w)) for k,
              (dt, c) in ARRAYS.items()}
    homs = np.repeat(np.eye(3)[None], n, 0)
    last2: list = []  # the pair's two frames, as the flow read them

    def feed():
        small = scale.ResizedFrames(frames, work)
        for t in range(len(small)):
            f = small[t]
            last2[:] = last2[-1:] + [f]
            yield f

    if cfg.method.startswith("raft"):
        model = raft.raft_model(cfg.raft_weights, None if cfg.method == "raft" else cfg.method[5:], device)
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
    (out
     / "flow.json").write_text(json.dumps({"pairs": n, "working_size": [h, w],
                                           "arrays": {k: [np.dtype(dt).str, c] for k,
                                                      (dt, c) in ARRAYS.items()}}))
    if n == 0:
        return {"pairs": 0}
    px = n * h * w
    return {"pairs": n, "working_size": [h, w], "mean_flow_px": mag_sum / px, "consistent_fraction": ok_sum / px}


def load(out: Path) -> FlowArrays | None:
    """The arrays :func:`compute` left in ``out`` (opened, not read), or None for a single frame."""
    out = Path(out)
    info = json.loads((out / "flow.json").read_text())
    n = info["pairs"]
    if not n:
        return None
    h, w = info["working_size"]
    fl = {k: DiskArray(out / f"{k}.raw", dt, (n, h, w, 2) if c else (n, h, w)) for k, (dt, c) in info["arrays"].items()}
    return FlowArrays.of({**fl, "homs": np.load(out / "homs.npy")})


def at_frame_size(fl, hw: tuple[int, int], keys: tuple | None = None):
    """The flow stage's arrays (flows ``fw``/``bw``, masks ``fw_ok``/``bw_ok``/``vis``, homographies
    ``homs``), computed at a working size, at the frames' size ``hw``: flows upsampled (in frame
    pixels), masks by nearest pixel, homographies rescaled. ``keys``: only these (the others are
    left out); ``fl`` itself when the sizes agree. A :class:`~layercam.vision.flow_store.FlowArrays`
    gives one (the left-out arrays None), any other mapping a dict."""
    if fl is None:
        return None
    work = tuple(fl["fw"].shape[1:3])
    if work == tuple(hw):
        return fl
    out = {}
    for k in keys or tuple(fl):
        if k in ("fw", "bw"):
            out[k] = scale.upsample_flow(fl[k], hw)
        elif k in ("fw_ok", "bw_ok", "vis"):
            out[k] = scale.upsample_mask(fl[k], hw)
        elif k == "homs":
            out[k] = scale.rescale_homographies(fl[k], work, hw)
    return FlowArrays.of(out) if isinstance(fl, FlowArrays) else out
