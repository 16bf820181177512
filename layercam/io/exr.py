"""OpenEXR images (linear HDR): ``(H,W,3)`` float RGB, ZIP-compressed scanline files, via the
``OpenEXR`` 3.x package (OpenCV's wheel has no EXR and imageio misreads it). Imported lazily.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from layercam.core.errors import LayercamError
from layercam.io.atomic import atomic_write

__all__ = ["write_exr", "read_exr"]


def write_exr(path: str | os.PathLike, img: np.ndarray, half: bool = True) -> Path:
    """Write ``img`` ``(H,W,3)`` float (linear RGB, any range) as an EXR with channels R,G,B.

    ``half=True`` stores float16 (~3e-4 relative error; values beyond 65504 become inf, so
    they raise), otherwise float32. ZIP compression, atomic write. Non-finite input raises
    ``ValueError``: the caller must not write NaN/inf.
    """
    import OpenEXR

    img = np.asarray(img)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"write_exr expects (H,W,3), got shape {img.shape}")
    if img.shape[0] == 0 or img.shape[1] == 0:
        raise ValueError(f"write_exr got an empty image {img.shape}")
    if not np.issubdtype(img.dtype, np.number):
        raise ValueError(f"write_exr expects numeric data, got {img.dtype}")
    arr = img.astype(np.float32, copy=False)
    if not np.all(np.isfinite(arr)):
        raise ValueError("write_exr got non-finite values (NaN or inf); refusing to write")
    if half:
        if np.abs(arr).max() > 65504.0:
            raise ValueError("write_exr: values exceed the float16 range (65504); use half=False")
        arr = arr.astype(np.float16)
    arr = np.ascontiguousarray(arr)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}

    def _write(tmp: Path) -> None:
        with OpenEXR.File(header, {"RGB": arr}) as f:
            f.write(str(tmp))

    return atomic_write(path, _write)


def read_exr(path: str | os.PathLike) -> np.ndarray:
    """Read an EXR file as float32 ``(H,W,3)`` RGB (grey ``Y`` is replicated, alpha dropped).

    Raises ``LayercamError`` if the file is missing, corrupt or has no colour channels.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"read_exr expects a path, got {type(path).__name__}")
    p = Path(path).expanduser()
    if not p.is_file():
        raise LayercamError(f"EXR file not found: {p}")
    import OpenEXR

    try:
        with OpenEXR.File(str(p)) as f:
            ch = {name: np.asarray(c.pixels) for name, c in f.channels().items()}
    except Exception as e:  # noqa: BLE001 - OpenEXR raises plain RuntimeError/Exception types
        raise LayercamError(f"cannot read EXR {p}: {str(e).strip()[:160] or type(e).__name__}") from None
    if "RGB" in ch:
        out = ch["RGB"]
    elif "RGBA" in ch:
        out = ch["RGBA"][..., :3]
    elif all(k in ch for k in ("R", "G", "B")):
        out = np.stack([ch["R"], ch["G"], ch["B"]], axis=-1)
    elif "Y" in ch:
        out = np.repeat(np.asarray(ch["Y"])[..., None], 3, axis=-1)
    else:
        raise LayercamError(f"EXR {p} has no RGB or Y channels (found {sorted(ch)})")
    return np.ascontiguousarray(out, dtype=np.float32)
