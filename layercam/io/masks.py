"""Foreground masks: a folder of per-frame mask images -> ``(T, H, W)`` float32 in {0, 1} for a clip.

Masks (e.g. DAVIS annotations, Mask R-CNN output as in layered neural atlases) guide the alpha
field of a two-layer scene. One image per source frame, in natural name order; grey, RGB or
palette images all work (any non-zero colour channel counts), 0/1 and 0/255 alike.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from layercam.core.errors import LayercamError
from layercam.io.clip import Clip
from layercam.io.inputs import natural_key, resize

__all__ = ["MASK_SUFFIXES", "list_masks", "load_masks"]

MASK_SUFFIXES: tuple[str, ...] = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


def list_masks(folder: str | os.PathLike) -> list[Path]:
    """Mask image files of ``folder`` in natural order (``2.png`` before ``10.png``); hidden files skipped."""
    p = Path(folder).expanduser()
    if not p.exists():
        raise LayercamError(f"mask folder not found: {p}")
    if not p.is_dir():
        raise LayercamError(f"masks must be a folder of images, got a file: {p}")
    files = [q for q in p.iterdir() if q.is_file() and not q.name.startswith(".") and q.suffix.lower() in MASK_SUFFIXES]
    if not files:
        raise LayercamError(f"mask folder {p} has no images ({'/'.join(s[1:] for s in MASK_SUFFIXES)})")
    return sorted(files, key=lambda q: natural_key(q.name))


def _read_mask(path: Path) -> np.ndarray:
    """One mask file -> ``(h, w)`` float32 (raw levels; colour reduced by max over channels)."""
    import cv2

    try:
        buf = np.fromfile(str(path), dtype=np.uint8)
    except OSError as e:
        raise LayercamError(f"cannot read mask {path}: {e.strerror or e}") from None
    arr = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if buf.size else None
    if arr is None:
        raise LayercamError(f"cannot decode mask {path} (corrupt or unsupported format)")
    if arr.ndim == 3:
        if arr.shape[2] in (2, 4):  # grey+alpha / colour+alpha: the mask is in the colour channels,
            colour = arr[:, :, : arr.shape[2] - 1]  # unless they are all zero (mask stored as alpha)
            arr = colour if colour.any() else arr[:, :, -1:]
        arr = arr.max(axis=2)
    return np.nan_to_num(arr.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)


def _select(paths: list[Path], clip: Clip, folder) -> list[Path]:
    t = clip.T
    if len(paths) < t:
        raise LayercamError(f"mask folder {folder} has {len(paths)} masks but the clip has {t} frames")
    if len(paths) == t:
        return paths
    idx = clip.meta.get("frame_indices") if isinstance(clip.meta, dict) else None
    if idx is None or len(idx) != t:
        return paths[:t]
    idx = [int(i) for i in idx]
    if max(idx) >= len(paths):
        raise LayercamError(
            f"mask folder {folder} has {len(paths)} masks but the clip uses source frame {max(idx)}"
        )
    return [paths[i] for i in idx]


def load_masks(folder: str | os.PathLike, clip: Clip, own_size: bool = False) -> np.ndarray:
    """Foreground masks for ``clip``: ``(T, H, W)`` float32 in {0, 1} at the clip's size (with
    ``own_size``, at the first mask's own size: the truth's resolution, for scoring there).

    One image per frame, natural order. With exactly ``T`` masks they are taken in order; with more,
    the ones at ``clip.meta["frame_indices"]`` (the source index of each kept frame, so strided
    or truncated clips still match), else the first ``T``. Colour channels are combined (any non-zero
    channel); each mask, as a share of the largest level over all the selected masks (0/1 and 0/255
    masks alike; all-zero masks stay empty), is resized to ``(H, W)`` as the frames are (area average
    when shrinking, bilinear when growing: the same pixel grid, and a pixel's share of the object), and a
    pixel is foreground when that share is > 0.5. Problems raise ``LayercamError`` with a one-line message.
    For a clip kept on disk (``load_clip(..., cache=...)``: ``clip.meta["frames_cache"]``) the masks
    are a uint8 :class:`~layercam.io.frames.DiskArray` of 0 and 1 in an unlinked file beside its
    frames, read as needed: their memory does not grow with the clip.
    """
    paths = _select(list_masks(folder), clip, Path(folder).expanduser())
    shape, peak = None, 0.0
    for p in paths:  # a first pass: the largest level over all (and the first mask's size)
        m = _read_mask(p)
        shape, peak = shape or m.shape[:2], max(peak, float(m.max()))
    h, w = shape if own_size else (clip.H, clip.W)

    def read(p) -> np.ndarray:  # the mask's share of the object at the clip's pixels, > 0.5
        return resize(_read_mask(p) / peak, (w, h)) > 0.5 if peak > 0 else np.zeros((h, w), bool)

    cache = (clip.meta or {}).get("frames_cache")
    if cache:  # a clip kept on disk: its masks too, a mask read at a time
        from layercam.io.frames import TempArray

        out = TempArray(np.uint8, (clip.T, h, w), cache)
        for i, p in enumerate(paths):
            out[i] = read(p)
        return out
    return np.stack([read(p) for p in paths]).astype(np.float32)
