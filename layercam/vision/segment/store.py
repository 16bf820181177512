"""Masks on disk (``masks.npz`` for training, PNGs to look at) and where they are trusted."""

from __future__ import annotations

import numpy as np


def sure_pixels(masks: np.ndarray, band: float) -> np.ndarray:
    """Where masks ``(T, H, W)`` are trusted: pixels farther than ``band`` (a share of the short
    side) from the other class, so a band around each mask's edge is left out. A frame without any
    mask pixel is sure everywhere."""
    import cv2

    m = np.asarray(masks) > 0.5
    px = band * min(m.shape[1:])
    out = np.ones(m.shape, dtype=bool)
    if px <= 0:
        return out
    for t, f in enumerate(m):
        if f.any() and not f.all():
            u = f.astype(np.uint8)
            d_in = cv2.distanceTransform(u, cv2.DIST_L2, 3)       # inside: distance to the nearest outside pixel
            d_out = cv2.distanceTransform(1 - u, cv2.DIST_L2, 3)  # outside: to the nearest mask pixel
            out[t] = np.where(f, d_in, d_out) > px
    return out


def load_masks(folder) -> np.ndarray | None:
    """The masks :func:`save_masks` wrote in ``folder``, ``(T, H, W)`` float32 in {0, 1}; None without."""
    from pathlib import Path

    path = Path(folder) / "masks.npz"
    if not path.exists():
        return None
    with np.load(path) as z:
        return z["masks"].astype(np.float32)


def save_masks(folder, masks: np.ndarray) -> None:
    """``masks.npz`` (what training reads) and ``masks/frame_00000.png`` (to look at) in ``folder``."""
    from pathlib import Path

    from layercam.io import write_png

    folder = Path(folder)
    np.savez_compressed(folder / "masks.npz", masks=(np.asarray(masks) > 0.5))
    (folder / "masks").mkdir(exist_ok=True)
    for t, m in enumerate(masks):
        write_png(folder / "masks" / f"frame_{t:05d}.png", (m > 0.5).astype(np.float32))
