"""A clip's input before it is decoded: which files (a video, a folder of images, a list or a glob
of them, :func:`expand_inputs`), which frames (``--stride``, ``--max-frames``: :func:`check_count`)
at what size (``--resize``: :func:`parse_resize`, :func:`target_size`, :func:`resize`), the key of
the decoded clip in the cache (:func:`source_key`), the frames' names, their primaries and the sound
the outputs carry over (:func:`primaries_of`, :func:`audio_plan`). :mod:`layercam.io.decode` reads
the input through them."""

from __future__ import annotations

import glob
import hashlib
import os
import re
from pathlib import Path

import numpy as np

from layercam.core.errors import LayercamError
from layercam.io.images import IMAGE_SUFFIXES
from layercam.io.video import VIDEO_SUFFIXES

__all__ = ["FRAMES_VERSION", "EXIF_SUFFIXES", "alpha_note", "audio_plan", "check_count",
           "expand_inputs", "list_folder", "natural_key",
           "parse_resize", "primaries_of", "resize", "source_key", "target_size", "unique_names"]

FRAMES_VERSION = 2  # the layout of a decoded clip in the cache (frames-<key>/frames.raw + clip.json): part of its key

EXIF_SUFFIXES = (".jpg", ".jpeg", ".tif", ".tiff")
_GLOB_CHARS = re.compile(r"[*?\[]")


def natural_key(name: str) -> list:
    """Sort key that orders ``frame2`` before ``frame10``."""
    return [int(tok) if tok.isdigit() else tok.lower() for tok in re.split(r"(\d+)", name)]


def parse_resize(resize) -> tuple[str, float | tuple[int, int]] | None:
    """Parse a resize option: None, a factor (``0.5``, ``"0.5"``) or ``"WxH"``.

    Returns None, ``("factor", f)`` or ``("size", (W, H))``; bad values raise ``LayercamError``.
    """
    if resize is None:
        return None
    if isinstance(resize, bool):
        raise LayercamError(f"bad resize {resize!r}: give a factor like 0.5 or a size like 640x360")
    if isinstance(resize, (int, float, np.integer, np.floating)):
        f = float(resize)
    elif isinstance(resize, (tuple, list)) and len(resize) == 2:
        try:
            w, h = (int(v) for v in resize)
        except (TypeError, ValueError):
            raise LayercamError(f"bad resize {resize!r}: expected (W, H)") from None
        if w < 1 or h < 1:
            raise LayercamError(f"bad resize {resize!r}: width and height must be >= 1")
        return ("size", (w, h))
    elif isinstance(resize, str):
        s = resize.strip().lower()
        m = re.fullmatch(r"(\d+)\s*[x×]\s*(\d+)", s)
        if m:
            w, h = int(m.group(1)), int(m.group(2))
            if w < 1 or h < 1:
                raise LayercamError(f"bad resize {resize!r}: width and height must be >= 1")
            return ("size", (w, h))
        try:
            f = float(s)
        except ValueError:
            raise LayercamError(
                f"bad resize {resize!r}: give a factor like 0.5 or a size like 640x360"
            ) from None
    else:
        raise LayercamError(f"bad resize {resize!r}: give a factor like 0.5 or a size like 640x360")
    if not np.isfinite(f) or f <= 0:
        raise LayercamError(f"bad resize factor {resize!r}: must be a positive number")
    return ("factor", f)


def target_size(rs, w: int, h: int) -> tuple[int, int]:
    if rs is None:
        return (w, h)
    kind, val = rs
    if kind == "size":
        return val  # type: ignore[return-value]
    return (max(1, int(round(w * val))), max(1, int(round(h * val))))


def resize(img: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    import cv2

    w, h = size
    if (img.shape[1], img.shape[0]) == (w, h):
        return img
    down = w * h < img.shape[0] * img.shape[1]
    interp = cv2.INTER_AREA if down else cv2.INTER_LINEAR
    out = cv2.resize(img, (w, h), interpolation=interp)
    return np.clip(out, 0.0, 1.0).astype(np.float32, copy=False)


def check_count(name: str, value, minimum: int) -> None:
    if value is None and name == "max_frames":
        return
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise LayercamError(f"{name} must be an integer >= {minimum}, got {value!r}")


def list_folder(folder: Path) -> list[Path]:
    files = [
        p
        for p in folder.iterdir()
        if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in IMAGE_SUFFIXES
    ]
    if not files:
        videos = [p.name for p in folder.iterdir() if p.suffix.lower() in VIDEO_SUFFIXES]
        hint = f" (it has video {videos[0]}: pass the file itself)" if videos else ""
        raise LayercamError(
            f"folder {folder} has no images ({'/'.join(s[1:] for s in IMAGE_SUFFIXES)}){hint}"
        )
    return sorted(files, key=lambda p: natural_key(p.name))


def expand_inputs(inputs) -> tuple[str, list[Path] | Path]:
    """Return ("video", path) or ("images", [paths]) for the user's input."""
    if isinstance(inputs, (str, os.PathLike)):
        s = os.fspath(inputs)
        if isinstance(s, str) and s.startswith("synthetic:"):
            raise LayercamError(f"{s!r} is a synthetic clip: build it with layercam.synth, not load_clip")
        p = Path(s).expanduser()
        if p.is_dir():
            return ("images", list_folder(p))
        if p.is_file():
            if p.suffix.lower() in IMAGE_SUFFIXES:
                return ("images", [p])
            return ("video", p)  # any other file: let ffmpeg decide (errors say what it is)
        if _GLOB_CHARS.search(s):
            hits = [Path(h) for h in glob.glob(os.path.expanduser(s))]
            hits = [h for h in hits if h.is_file() and h.suffix.lower() in IMAGE_SUFFIXES]
            if not hits:
                raise LayercamError(f"no images match {s}")
            return ("images", sorted(hits, key=lambda q: natural_key(q.name)))
        raise LayercamError(f"input not found: {p}")
    if isinstance(inputs, (list, tuple)):
        if not inputs:
            raise LayercamError("no input frames given (empty list)")
        if len(inputs) == 1:
            return expand_inputs(inputs[0])
        paths: list[Path] = []
        for item in inputs:
            if not isinstance(item, (str, os.PathLike)):
                raise TypeError(f"load_clip list items must be paths, got {type(item).__name__}")
            p = Path(item).expanduser()
            if p.is_dir():
                raise LayercamError(f"{p} is a folder: pass either one folder or a list of image files")
            if not p.exists():
                raise LayercamError(f"image not found: {p}")
            if p.suffix.lower() not in IMAGE_SUFFIXES:
                raise LayercamError(
                    f"{p.name} is not an image ({'/'.join(s[1:] for s in IMAGE_SUFFIXES)}); "
                    "pass a video on its own"
                )
            paths.append(p)
        return ("images", paths)
    raise TypeError(f"load_clip expects a path or a list of paths, got {type(inputs).__name__}")


def unique_names(paths: list[Path]) -> list[str]:
    names, seen = [], {}
    for p in paths:
        stem = p.stem
        n = seen.get(stem, 0)
        seen[stem] = n + 1
        names.append(stem if n == 0 else f"{stem}_{n}")
    return names


def source_key(kind: str, what, stride: int, max_frames: int | None, rs) -> str:
    """What names a decoded clip in the cache: the files (path, size, modification time), the
    frames taken and the resize."""
    files = [what] if kind == "video" else list(what)
    ident = []
    for p in files:
        st = Path(p).stat()
        ident.append([str(Path(p).resolve()), st.st_size, st.st_mtime_ns])
    blob = repr((FRAMES_VERSION, kind, ident, stride, max_frames, rs)).encode()
    return hashlib.sha1(blob).hexdigest()[:12]


def primaries_of(tag: str | None) -> dict:
    """The colour primaries of a clip's RGB: the input's tag where it names primaries
    :mod:`layercam.core.bt2100` knows, else BT.709 / sRGB (what 8-bit video and images without tags
    are), said as assumed."""
    from layercam.core.bt2100 import PRIMARIES

    if tag in PRIMARIES:
        return {"name": tag, "how": "tagged in the input"}
    said = f" (the input says {tag}, not known here)" if tag else ""
    return {"name": "bt709", "how": f"assumed: BT.709 / sRGB, as untagged 8-bit video and images are{said}"}


def audio_plan(path: Path, info: dict, n: int, fps: float, stride: int,
               max_frames: int | None) -> tuple[dict | None, list[str]]:
    """The sound the videos written from a clip of ``n`` frames carry over from the input ``path``
    (``{"path", "codec", "duration"}``: the input's first audio stream from its start, cut at
    ``duration`` seconds when ``--max-frames`` ended the clip early; None without sound or with a
    stride, whose frames no longer keep the input's time) and the lines a run says about timing
    and sound (a variable frame rate, sound dropped)."""
    notes = []
    if info.get("variable"):
        notes.append(f"{path.name} has a variable frame rate ({info['fps']:g} fps on average): its "
                     "frames are taken at a constant "
                     f"{fps:g} fps (ffmpeg repeats or drops a frame where the timing needs it, so "
                     f"the sound stays in step), and every video is written at {fps:g} fps")
    if not info.get("audio"):
        return None, notes
    if stride > 1:
        notes.append(f"--stride {stride}: the sound of {path.name} is dropped (every {stride}th "
                     f"frame played at {fps:g} fps no longer keeps the input's time)")
        return None, notes
    span = n / fps
    dur = info.get("duration")
    cut = max_frames is not None and n == max_frames and (dur is None or span < dur - 0.5 / fps)
    return {"path": str(path.resolve()), "codec": info["audio"], "duration": span if cut else None}, notes


def alpha_note(transparent: list[float], n: int) -> str:
    """One line for frames whose alpha channel is dropped (layercam reads RGB)."""
    part = f"{max(transparent):.0%} of the pixels transparent at most" if max(transparent) > 0 else "fully opaque"
    return (f"{len(transparent)} of {n} frames have an alpha channel ({part}): alpha is dropped, "
            "the RGB values are used as they are")
