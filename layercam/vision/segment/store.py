"""Masks on disk (``masks.npz`` for training, PNGs to look at) and where they are trusted."""

from __future__ import annotations

import numpy as np


def sure_pixels(masks: np.ndarray, band: float, out=None) -> np.ndarray:
    """Where masks ``(T, H, W)`` are trusted: pixels farther than ``band`` (a share of the short
    side) from the other class, so a band around each mask's edge is left out. A frame without any
    mask pixel is sure everywhere. ``out``: a ``(T, H, W)`` bool array to fill (a
    :class:`~layercam.io.frames.DiskArray` for a long clip), returned."""
    import cv2

    px = band * min(masks.shape[1:])
    if out is None:
        out = np.ones(masks.shape, dtype=bool)
    if px <= 0:
        out[0 : len(out)] = True
        return out
    for t in range(len(masks)):  # a frame at a time (masks and out may be on disk)
        f = np.asarray(masks[t]) > 0.5
        if not f.any() or f.all():
            out[t] = True
        else:
            u = f.astype(np.uint8)
            d_in = cv2.distanceTransform(u, cv2.DIST_L2, 3)       # inside: distance to the nearest outside pixel
            d_out = cv2.distanceTransform(1 - u, cv2.DIST_L2, 3)  # outside: to the nearest mask pixel
            out[t] = np.where(f, d_in, d_out) > px
    return out


def load_masks(folder) -> np.ndarray | None:
    """The masks :func:`save_masks` wrote in ``folder``, ``(T, H, W)`` float32 in {0, 1} (a long
    clip's, :func:`foreground_bootstrap_long`: a uint8 :class:`~layercam.io.frames.DiskArray` of
    0 and 1, read as needed); None without."""
    import json
    from pathlib import Path

    from layercam.io.frames import DiskArray

    raw = Path(folder) / "masks.raw"
    if raw.exists():
        return DiskArray(raw, np.uint8, json.loads((Path(folder) / "masks.json").read_text())["shape"])
    path = Path(folder) / "masks.npz"
    if not path.exists():
        return None
    with np.load(path) as z:
        return z["masks"].astype(np.float32)


def save_masks(folder, masks: np.ndarray) -> None:
    """``masks.npz`` (what training reads; a long clip's are in ``masks.raw`` already, written by
    :func:`foreground_bootstrap_long`) and ``masks/frame_00000.png`` (to look at) in ``folder``."""
    from pathlib import Path

    from layercam.io import write_png
    from layercam.io.frames import DiskArray

    folder = Path(folder)
    if not isinstance(masks, DiskArray):
        np.savez_compressed(folder / "masks.npz", masks=(np.asarray(masks) > 0.5))
    (folder / "masks").mkdir(exist_ok=True)
    for t in range(len(masks)):
        write_png(folder / "masks" / f"frame_{t:05d}.png", (np.asarray(masks[t]) > 0.5).astype(np.float32))


def mask_coverage(masks) -> np.ndarray:
    """Per frame ``(T,)``: the share of the frame the mask covers (read a frame at a time)."""
    return np.array([float(np.mean(np.asarray(masks[t]) > 0.5)) for t in range(len(masks))])
