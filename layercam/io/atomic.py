"""Atomic file writes: write to a temporary sibling file, then ``os.replace`` it into place.

A reader never sees a half-written output, and an interrupted run leaves no partial file
under the final name.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import tempfile
import uuid
from pathlib import Path
from typing import Callable

from layercam.core.errors import LayercamError

__all__ = ["atomic_write", "ensure_writable_dir", "staging_dir", "commit_staged", "replace_entry",
           "temp_name", "write_failure", "partials_removed_on_error"]


def write_failure(path: Path, e: BaseException) -> LayercamError | None:
    """The one-line error for a write of ``path`` that failed with ``e``, or None when ``e`` is not
    a failure to write: an ``OSError`` (a full disk, a quota, a read-only or vanished folder) or
    the ``RuntimeError`` torch's zip writer and OpenEXR raise for a full disk."""
    first = (str(e).splitlines() or [type(e).__name__])[0]
    if isinstance(e, OSError):
        said = (" (the disk is full)" if e.errno in (errno.ENOSPC, errno.EDQUOT)
                else " (is the disk full?)" if e.errno is None else "")
        return LayercamError(f"cannot write {path}{said}: {e.strerror or first}")  # no errno: PIL's short write
    if isinstance(e, RuntimeError) and "No space left on device" in str(e):  # OpenEXR's writer
        return LayercamError(f"cannot write {path} (the disk is full): {first}")
    if isinstance(e,
                  RuntimeError) and any(k in first
                                        for k in ("inline_container", "iostream error",
                                                  "Failed to write")):
        return LayercamError(f"cannot write {path} (is the disk full?): {first}")
    return None


def ensure_writable_dir(path: str | os.PathLike) -> Path:
    """Create folder ``path`` (with parents) and check that files can be written in it.

    Returns the folder as a ``Path``. Raises ``LayercamError`` (one line) when it cannot be
    created (e.g. a file stands where a folder is expected) or is not writable.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"ensure_writable_dir expects a path, got {type(path).__name__}")
    p = Path(path).expanduser()
    if p.exists() and not p.is_dir():
        raise LayercamError(f"output folder {p} is a file, not a folder")
    try:
        p.mkdir(parents=True, exist_ok=True)
    except (OSError, FileExistsError) as e:
        raise LayercamError(f"cannot create output folder {p}: {e.strerror or e}") from None
    try:
        fd, probe = tempfile.mkstemp(prefix=".layercam_write_probe_", dir=p)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise LayercamError(f"output folder {p} is not writable: {e.strerror or e}") from None
    return p


def temp_name(path: Path) -> Path:
    """Hidden sibling temp name that keeps the full suffix, e.g. ``.frame_00000.<rand>.tmp.exr``."""
    suffix = "".join(path.suffixes[-1:])  # the last suffix decides the encoder
    stem = path.name[: len(path.name) - len(suffix)] if suffix else path.name
    return path.with_name(f".{stem}.{uuid.uuid4().hex[:8]}.tmp{suffix}")


def atomic_write(path: str | os.PathLike, writer: Callable[[Path], None]) -> Path:
    """Write ``path`` atomically: ``writer(tmp_path)`` fills a temp file in the same folder,
    which then replaces ``path``.

    The temp file has the same suffix as ``path`` (so encoders that pick the format from the
    suffix work) and is removed if ``writer`` raises or does not create it. The parent folder
    must exist or be creatable (``LayercamError`` otherwise). Returns the final ``Path``.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"atomic_write expects a path, got {type(path).__name__}")
    if not callable(writer):
        raise TypeError("atomic_write expects a callable writer(tmp_path)")
    final = Path(path).expanduser()
    if final.is_dir():
        raise LayercamError(f"cannot write {final}: it is a folder")
    parent = final.parent
    if not parent.is_dir():
        ensure_writable_dir(parent)
    tmp = temp_name(final)
    try:
        writer(tmp)
        if not tmp.exists():
            raise LayercamError(f"writing {final} produced no file")
        os.replace(tmp, final)
    except BaseException as e:
        try:
            tmp.unlink()
        except FileNotFoundError:
            pass
        except OSError:
            pass
        failed = write_failure(final, e)
        if failed is not None:
            raise failed from None
        raise
    return final


# -- sets of outputs: written in a staging folder, moved into place when complete ------------------
def staging_dir(dest: str | os.PathLike, tag: str) -> Path:
    """A fresh hidden folder ``dest/.partial-<tag>/`` to write a set of outputs into; whatever an
    interrupted command left there is removed first."""
    stage = Path(dest) / f".partial-{tag}"
    shutil.rmtree(stage, ignore_errors=True)
    stage.mkdir(parents=True)
    return stage


@contextlib.contextmanager
def partials_removed_on_error(dest: str | os.PathLike):
    """Around a command that writes sets of outputs into ``dest`` through :func:`staging_dir`: when
    it ends with an error (a full disk, Ctrl-C), the staging folders it left there are removed, so a
    failed write gives back the room it took (a render that filled the disk left each attempt's
    frames in ``.partial-*``). One command writes a folder at a time (``layercam.lock``)."""
    try:
        yield
    except BaseException:
        for p in Path(dest).glob(".partial-*"):
            shutil.rmtree(p, ignore_errors=True)
        raise


def replace_entry(src: Path, dst: Path) -> None:
    """Move file or folder ``src`` to ``dst``, replacing what is there (a folder is moved aside
    first, then removed, so ``dst`` is never a mix of old and new)."""
    src, dst = Path(src), Path(dst)
    if dst.is_dir() and not dst.is_symlink():
        old = dst.with_name(f".old-{dst.name}-{uuid.uuid4().hex[:8]}")
        os.rename(dst, old)
        os.rename(src, dst)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(src, dst)


def commit_staged(stage: Path, dest: Path, names: list[str]) -> None:
    """Move ``names`` from the staging folder ``stage`` into ``dest`` in order, each replacing what
    is there, then remove ``stage``. The last name marks the set finished (a sidecar written last)."""
    for n in names:
        replace_entry(Path(stage) / n, Path(dest) / n)
    shutil.rmtree(stage, ignore_errors=True)
