"""Still images: read any common 8/16-bit/float image as (H,W,3) float32 RGB in [0,1],
write 8/16-bit PNG atomically, read the EXIF exposure time.

OpenCV is imported lazily (inside the functions) so importing this module is cheap.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from layercam.core.errors import LayercamError
from layercam.io.atomic import atomic_write

__all__ = ["IMAGE_SUFFIXES", "read_image", "write_png", "read_exif_exposure", "image_bit_depth"]

IMAGE_SUFFIXES: tuple[str, ...] = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")


def _check_path(path) -> Path:
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"expected a path, got {type(path).__name__}")
    p = Path(path).expanduser()
    if not p.exists():
        raise LayercamError(f"image not found: {p}")
    if p.is_dir():
        raise LayercamError(f"expected an image file, got a folder: {p}")
    return p


def image_bit_depth(arr: np.ndarray) -> int:
    """Bit depth of a decoded array: 8 (uint8), 16 (uint16) or 32 (float)."""
    if arr.dtype == np.uint8:
        return 8
    if arr.dtype == np.uint16:
        return 16
    return 32


def read_image(path: str | os.PathLike, return_bit_depth: bool = False, return_alpha: bool = False):
    """Read an image file as RGB float32 ``(H, W, 3)`` in ``[0, 1]``.

    Supports png/jpg/jpeg/tif/tiff/bmp, 8- and 16-bit integer and float TIFF. Grey ``(H,W)``
    or ``(H,W,1)`` is replicated to RGB, alpha is dropped, 8-bit is divided by 255, 16-bit by
    65535, float data is clipped to ``[0, 1]`` (non-finite values become 0).

    Returns ``img`` or, with ``return_bit_depth=True``, ``(img, bit_depth)`` where bit_depth is
    8, 16 or 32 (float); with ``return_alpha=True`` also the fraction of pixels that the dropped
    alpha channel made transparent in any part (None without an alpha channel), last. Raises
    ``LayercamError`` if the file is missing or cannot be decoded.
    """
    import cv2

    p = _check_path(path)
    # cv2.imread cannot open non-ASCII paths on some platforms: decode from bytes instead.
    try:
        buf = np.fromfile(str(p), dtype=np.uint8)
    except OSError as e:
        raise LayercamError(f"cannot read image {p}: {e.strerror or e}") from None
    arr = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if buf.size else None
    if arr is None:
        raise LayercamError(f"cannot decode image {p} (corrupt or unsupported format)")
    depth = image_bit_depth(arr)
    alpha = None
    if arr.ndim == 3 and arr.shape[2] in (2, 4):
        a = arr[:, :, -1]
        alpha = float((a < (1.0 if np.issubdtype(a.dtype, np.floating) else np.iinfo(a.dtype).max)).mean())
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[:, :, 0]
    if arr.ndim == 2:
        arr = np.repeat(arr[:, :, None], 3, axis=2)
    elif arr.ndim == 3 and arr.shape[2] == 4:
        arr = cv2.cvtColor(arr, cv2.COLOR_BGRA2RGB)
    elif arr.ndim == 3 and arr.shape[2] == 3:
        arr = cv2.cvtColor(arr, cv2.COLOR_BGR2RGB)
    elif arr.ndim == 3 and arr.shape[2] == 2:  # grey + alpha
        arr = np.repeat(arr[:, :, :1], 3, axis=2)
    else:
        raise LayercamError(f"unsupported image layout {arr.shape} in {p}")
    if arr.dtype == np.uint8:
        img = arr.astype(np.float32) / 255.0
    elif arr.dtype == np.uint16:
        img = arr.astype(np.float32) / 65535.0
    elif np.issubdtype(arr.dtype, np.floating):
        img = np.nan_to_num(arr.astype(np.float32), nan=0.0, posinf=1.0, neginf=0.0)
        img = np.clip(img, 0.0, 1.0)
    else:
        info = np.iinfo(arr.dtype)
        img = (arr.astype(np.float64) - info.min) / float(info.max - info.min)
        img = img.astype(np.float32)
        depth = info.bits
    img = np.ascontiguousarray(img, dtype=np.float32)
    out = (img,) + ((depth,) if return_bit_depth else ()) + ((alpha,) if return_alpha else ())
    return out if len(out) > 1 else img


def write_png(path: str | os.PathLike, img: np.ndarray, bit_depth: int = 8) -> Path:
    """Write ``img`` (float in [0,1], ``(H,W,3)`` RGB or ``(H,W)`` grey) as an 8- or 16-bit PNG.

    Values are clipped to [0,1] and rounded. The write is atomic. Raises ``ValueError`` on a
    bad shape, bit depth or non-finite values; ``LayercamError`` if the folder is unwritable.
    """
    import cv2

    img = np.asarray(img)
    if bit_depth not in (8, 16):
        raise ValueError(f"bit_depth must be 8 or 16, got {bit_depth}")
    if not (img.ndim == 2 or (img.ndim == 3 and img.shape[2] in (1, 3))):
        raise ValueError(f"write_png expects (H,W,3) or (H,W), got shape {img.shape}")
    if img.size == 0:
        raise ValueError("write_png got an empty image")
    if img.dtype == np.uint8:
        img = img.astype(np.float32) / 255.0
    elif img.dtype == np.uint16:
        img = img.astype(np.float32) / 65535.0
    img = img.astype(np.float32, copy=False)
    if not np.all(np.isfinite(img)):
        raise ValueError("write_png got non-finite values")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    scale, dtype = (255.0, np.uint8) if bit_depth == 8 else (65535.0, np.uint16)
    q = np.round(np.clip(img, 0.0, 1.0) * scale).astype(dtype)
    if q.ndim == 3:
        q = np.ascontiguousarray(q[:, :, ::-1])  # RGB -> BGR for OpenCV

    def _write(tmp: Path) -> None:
        ok, enc = cv2.imencode(".png", q)
        if not ok:
            raise LayercamError(f"PNG encoding failed for {path}")
        enc.tofile(str(tmp))

    return atomic_write(path, _write)


def read_exif_exposure(path: str | os.PathLike) -> float | None:
    """Exposure time in seconds from EXIF (``ExposureTime`` in the Exif sub-IFD), else None.

    Returns None for formats without EXIF, missing tags, or unreadable EXIF blocks.
    """
    p = _check_path(path)
    try:
        from PIL import ExifTags, Image

        with Image.open(p) as im:
            exif = im.getexif()
            value = exif.get_ifd(ExifTags.IFD.Exif).get(ExifTags.Base.ExposureTime)
            if value is None:  # some writers put it in IFD0
                value = exif.get(ExifTags.Base.ExposureTime)
    except Exception:  # noqa: BLE001 - any unreadable EXIF just means "unknown"
        return None
    if value is None:
        return None
    try:
        if isinstance(value, tuple) and len(value) == 2:
            t = float(value[0]) / float(value[1])
        else:
            t = float(value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    if not np.isfinite(t) or t <= 0:
        return None
    return t
