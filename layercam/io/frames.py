"""Arrays too long to hold: a clip's frames, its flows and masks, kept on disk and read as needed.

:class:`DiskArray` is an ``(N, ...)`` array stored raw in a file. Rows (``a[t]``, ``a[t0:t1]``,
``a[t, y0:y1]``) are read with ``pread`` into fresh arrays, so that reading a clip a frame or a
window at a time costs the memory of that frame or window, whatever N. Scattered elements
(``a.gather(t, y, x)``, the sampler's random pixels) are read through a memory map whose pages are
given back after each gather (``madvise(MADV_DONTNEED)``): the file stays in the page cache, which
the kernel may drop, and out of the process's resident memory.

:class:`Frames` is what ``Clip.frames`` holds: ``(T, H, W, 3)`` frames stored compactly (uint8 for
8-bit sources, uint16 for 16-bit, float32 for float data or a clip built in memory), read as float32
in ``[0, 1]``: ``frames[t]`` ``(H, W, 3)``, ``frames[t0:t1]`` ``(n, H, W, 3)``, ``for f in frames``
(one frame at a time), ``np.asarray(frames)`` (the whole clip: only for clips known to be short).
"""

from __future__ import annotations

import json
import mmap
import os
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["DiskArray", "Frames", "gather", "read_rows", "TempArray"]


def _index_rows(key, n: int):
    """``key``'s first element as rows: ``(start, stop, step, rest, squeeze)`` for an int or a
    slice on the first axis (``rest``: the index of the other axes), else None."""
    first, rest = (key[0], key[1:]) if isinstance(key, tuple) and key else (key, ())
    if isinstance(first, (int, np.integer)) and not isinstance(first, bool):
        i = int(first) + (n if first < 0 else 0)
        if not 0 <= i < n:
            raise IndexError(f"index {int(first)} is out of bounds for axis 0 with size {n}")
        return i, i + 1, 1, rest, True
    if isinstance(first, slice):
        a, b, st = first.indices(n)
        return a, b, st, rest, False
    if first is Ellipsis and not rest:
        return 0, n, 1, (), False
    return None


class DiskArray:
    """An ``(N, ...)`` array of ``dtype`` stored raw (C order) in the file ``path``.

    ``DiskArray.create(path, dtype, shape)`` makes the file (sparse, zeros) for writing rows:
    ``a[t] = row`` or ``a[t0:t1] = rows`` (``pwrite``); ``DiskArray(path, dtype, shape)`` opens it
    for reading. Indexing by an int or a slice on the first axis reads only those rows (``pread``);
    other indices (index arrays) read through the memory map (:meth:`gather`). ``np.asarray(a)``
    reads it whole. ``a.rows(t0, t1)`` is a view of rows ``t0:t1`` (the same file, nothing read).
    ``a.close()`` (or garbage collection) closes the file. ``offset``: the byte where row 0 begins.
    """

    def __init__(self, path: str | os.PathLike, dtype, shape: tuple, writable: bool = False,
                 _fd: int | None = None, offset: int = 0):
        self.path, self.dtype, self.shape = Path(path), np.dtype(dtype), tuple(int(s) for s in shape)
        self.row_shape = self.shape[1:]
        self.row_bytes = int(np.prod(self.row_shape, dtype=np.int64)) * self.dtype.itemsize
        self.writable, self._offset, self._owner = writable, int(offset), None
        self._fd = _fd if _fd is not None else os.open(self.path, os.O_RDWR if writable else os.O_RDONLY)
        size = os.fstat(self._fd).st_size
        if size < self._offset + self.nbytes:
            os.close(self._fd)
            self._fd = None
            raise ValueError(f"{self.path} holds {size} bytes, not the {self.nbytes} of a "
                             f"{self.dtype} array {self.shape}")
        self._map = None

    def rows(self, t0: int, t1: int) -> "DiskArray":
        """Rows ``t0:t1`` as a DiskArray on the same open file (nothing is read; it stays valid while
        this one is open)."""
        t0, t1 = max(int(t0), 0), max(min(int(t1), len(self)), max(int(t0), 0))
        v = object.__new__(type(self))
        v.__dict__.update(self.__dict__)
        v.shape, v._offset, v._map, v._owner = ((t1 - t0, *self.row_shape),
                                                self._offset + t0 * self.row_bytes, None, self)
        return v

    @classmethod
    def create(cls, path: str | os.PathLike, dtype, shape: tuple) -> "DiskArray":
        """A new file of the array's size (sparse: blocks are allocated as rows are written)."""
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_TRUNC, 0o644)
        nbytes = int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize
        os.ftruncate(fd, nbytes)
        return cls(path, dtype, shape, writable=True, _fd=fd)

    # -- what numpy code asks of an array --------------------------------------------------------
    @property
    def ndim(self) -> int:
        return len(self.shape)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64))

    @property
    def nbytes(self) -> int:
        return self.size * self.dtype.itemsize

    def __len__(self) -> int:
        return self.shape[0]

    def __iter__(self):
        for t in range(len(self)):
            yield self.read(t, t + 1)[0]

    def __array__(self, dtype=None, copy=None):
        a = self.read(0, len(self))
        return a if dtype is None else a.astype(dtype, copy=False)

    def astype(self, dtype, copy: bool = True) -> np.ndarray:
        """The whole array, read, as ``dtype`` (for arrays known to be small)."""
        return self.read(0, len(self)).astype(dtype, copy=False)

    def __repr__(self) -> str:
        return f"DiskArray({str(self.path)!r}, {self.dtype}, {self.shape})"

    # -- reading ---------------------------------------------------------------------------------
    def read(self, t0: int, t1: int) -> np.ndarray:
        """Rows ``t0:t1`` as a new array (one ``pread`` of their bytes)."""
        t0, t1 = max(int(t0), 0), min(int(t1), len(self))
        out = np.empty((max(t1 - t0, 0), *self.row_shape), self.dtype)
        view, off, done = memoryview(out.reshape(-1).view(np.uint8)), self._offset + t0 * self.row_bytes, 0
        while done < len(view):
            got = os.preadv(self._fd, [view[done:]], off + done)
            if got <= 0:
                raise OSError(f"{self.path}: short read at byte {off + done}")
            done += got
        return out

    def __getitem__(self, key):
        rows = _index_rows(key, len(self))
        if rows is None:  # index arrays: through the memory map
            return self._mapped_index(key)
        a, b, step, rest, squeeze = rows
        if step == 1:
            out = self.read(a, b)
        else:  # a strided read, row by row
            idx = range(a, b, step)
            out = np.stack([self.read(i, i + 1)[0] for i in idx]) if len(idx) else np.empty(
                (0, *self.row_shape), self.dtype)
        if squeeze:
            out = out[0]
        return out[rest] if rest else out

    def gather(self, *idx) -> np.ndarray:
        """``a[idx]`` for index arrays (one per leading axis: ``a.gather(t, y, x)``), read through
        the memory map; its pages are given back to the kernel afterwards."""
        try:
            return np.array(self._mapped()[idx])
        finally:
            self.release()

    def _mapped_index(self, key) -> np.ndarray:
        try:
            return np.array(self._mapped()[key])
        finally:
            self.release()

    def _mapped(self) -> np.ndarray:
        if self._map is None:
            if self.nbytes == 0:
                return np.empty(self.shape, self.dtype)
            self._map = mmap.mmap(self._fd, self._offset + self.nbytes, prot=mmap.PROT_READ)
        return np.frombuffer(self._map, self.dtype, count=self.size, offset=self._offset).reshape(self.shape)

    def release(self) -> None:
        """Gives the memory map's resident pages back (they stay in the page cache)."""
        if self._map is not None:
            self._map.madvise(mmap.MADV_DONTNEED)

    # -- writing ---------------------------------------------------------------------------------
    def __setitem__(self, key, value) -> None:
        rows = _index_rows(key, len(self))
        if not self.writable or rows is None or rows[2] != 1 or rows[3]:
            raise TypeError("a DiskArray is written whole rows at a time: a[t] = row or a[t0:t1] = "
                            "rows, opened with DiskArray.create")
        a, b = rows[0], rows[1]
        v = np.ascontiguousarray(np.broadcast_to(np.asarray(value, self.dtype), (b - a, *self.row_shape)))
        buf, off, done = memoryview(v.reshape(-1).view(np.uint8)), self._offset + a * self.row_bytes, 0
        while done < len(buf):
            done += os.pwritev(self._fd, [buf[done:]], off + done)

    def flush(self) -> None:
        if self.writable:
            os.fsync(self._fd)

    def close(self) -> None:
        if self._map is not None:
            self._map.close()
            self._map = None
        if self._fd is not None and self._owner is None:  # a view (rows) leaves its owner's file open
            os.close(self._fd)
        self._fd = None

    def __del__(self):
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass

    def __getstate__(self):  # to another process (torch.distributed, Ray): the path, reopened there
        return {"path": str(self.path), "dtype": self.dtype.str, "shape": self.shape, "offset": self._offset}

    def __setstate__(self, s):
        self.__init__(s["path"], s["dtype"], s["shape"], offset=s.get("offset", 0))


class TempArray(DiskArray):
    """A :class:`DiskArray` in a file of its own that nobody else sees: created in ``folder`` (the
    system's temporary folder by default) and unlinked at once, so that it disappears when closed,
    however the process ends."""

    def __init__(self, dtype, shape: tuple, folder: str | os.PathLike | None = None):
        fd, name = tempfile.mkstemp(prefix="layercam-", suffix=".raw", dir=folder)
        os.unlink(name)
        nbytes = int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize
        os.ftruncate(fd, nbytes)
        super().__init__(name, dtype, shape, writable=True, _fd=fd)

    def __getstate__(self):
        raise TypeError("a TempArray cannot be sent to another process (its file is unlinked)")


def gather(a, *idx) -> np.ndarray:
    """``a[idx]`` for index arrays, from an ndarray or a :class:`DiskArray` (through its memory map)."""
    return a.gather(*idx) if isinstance(a, DiskArray) else np.asarray(a)[idx]


def read_rows(a, t0: int, t1: int) -> np.ndarray:
    """Rows ``t0:t1`` of an ndarray (a view) or a :class:`DiskArray` (read)."""
    return a.read(t0, t1) if isinstance(a, DiskArray) else np.asarray(a[t0:t1])


SCALES = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0, np.dtype(np.float32): 1.0}


class Frames:
    """A clip's frames ``(T, H, W, 3)``, read as float32 in ``[0, 1]``.

    ``raw``: the stored values, an ndarray or a :class:`DiskArray` of uint8 (``value / 255``),
    uint16 (``value / 65535``) or float32 (as they are). Indexing on the first axis (``f[t]``,
    ``f[t0:t1]``, ``f[t, y0:y1]``) reads those frames only and returns float32; iteration gives one
    frame at a time; ``np.asarray(f)`` the whole clip as float32 (for clips known to be short).
    ``f.gather(t, y, x)`` reads scattered pixels ``(N, 3)`` (the sampler's batches).
    """

    dtype = np.dtype(np.float32)
    ndim = 4

    def __init__(self, raw):
        if np.dtype(raw.dtype) not in SCALES:
            raw = np.asarray(raw, np.float32)
        if len(raw.shape) != 4 or raw.shape[3] != 3:
            raise ValueError(f"frames must be (T,H,W,3), got shape {tuple(raw.shape)}")
        self.raw = raw
        self.scale = np.float32(SCALES[np.dtype(raw.dtype)])
        self.shape = tuple(int(s) for s in raw.shape)

    def _float(self, a: np.ndarray) -> np.ndarray:
        if a.dtype == np.float32:
            return a
        return a.astype(np.float32) / self.scale  # as read_image and load_clip divided: the same float32 values

    @property
    def on_disk(self) -> bool:
        return isinstance(self.raw, DiskArray)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64))

    @property
    def frame_bytes(self) -> int:
        """Bytes of one stored frame."""
        return int(np.prod(self.shape[1:])) * np.dtype(self.raw.dtype).itemsize

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key):
        return self._float(self.raw[key])

    def rows(self, t0: int, t1: int) -> "Frames":
        """Frames ``t0:t1`` as Frames of their own, nothing read (a view of the same storage)."""
        return Frames(self.raw.rows(t0, t1) if self.on_disk else self.raw[t0:t1])

    def __iter__(self):
        for t in range(len(self)):
            yield self[t]

    def __array__(self, dtype=None, copy=None):
        a = self._float(np.asarray(self.raw))
        return a if dtype is None else a.astype(dtype, copy=False)

    def astype(self, dtype, copy: bool = True) -> np.ndarray:
        return np.asarray(self).astype(dtype, copy=copy)

    def gather(self, *idx) -> np.ndarray:
        return self._float(gather(self.raw, *idx))

    def __repr__(self) -> str:
        return f"Frames({self.shape}, stored as {np.dtype(self.raw.dtype)}{' on disk' if self.on_disk else ''})"

    # ndarray methods and operators, on the whole clip in float32: for short clips (tests, a stack
    # of photos); the stages read frames and windows by index instead
    def __getattr__(self, name):
        if name in _WHOLE:
            return getattr(np.asarray(self), name)
        raise AttributeError(f"'Frames' object has no attribute {name!r}")


_WHOLE = ("mean", "max", "min", "sum", "std", "reshape", "copy", "ravel", "flatten", "transpose",
          "tolist", "any", "all", "clip", "squeeze", "T")


def _whole(op: str):
    def f(self, *args):
        return getattr(np.asarray(self), op)(*args)

    f.__name__ = op
    return f


for _op in ("__add__", "__radd__", "__sub__", "__rsub__", "__mul__", "__rmul__", "__truediv__",
            "__rtruediv__", "__pow__",
            "__lt__", "__le__", "__gt__", "__ge__", "__neg__", "__abs__"):
    setattr(Frames, _op, _whole(_op))


def write_meta(path: Path, meta: dict) -> None:
    from layercam.io.atomic import atomic_write

    atomic_write(path, lambda p: p.write_text(json.dumps(meta, indent=1)))
