"""A clip: the frames of one input (video file, folder of images, list of images) as
``(T,H,W,3)`` float32 RGB in [0,1], with per-frame names, fps, bit depth and EXIF exposures.
"""

from __future__ import annotations

import glob
import hashlib
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from layercam.errors import LayercamError
from layercam.io.images import IMAGE_SUFFIXES, read_exif_exposure, read_image
from layercam.io.video import VIDEO_SUFFIXES, read_video

__all__ = ["Clip", "load_clip", "parse_resize", "natural_key"]

_EXIF_SUFFIXES = (".jpg", ".jpeg", ".tif", ".tiff")
_GLOB_CHARS = re.compile(r"[*?\[]")


@dataclass
class Clip:
    """Frames of one input and what is known about them.

    frames: ``(T,H,W,3)`` float32 RGB in [0,1].
    source: what the user passed (a path, or e.g. ``"synthetic:..."``).
    names: ``T`` per-frame stems (``"00000"`` for video frame 0, ``"IMG_2600"`` for images).
    fps: frames per second (24 when unknown, e.g. for image folders).
    bit_depth: 8, 16 or 32 (float) of the source data.
    exif_exposures: ``T`` EXIF exposure times in seconds (None where absent) for image inputs,
        else None.
    meta: free-form; ``load_clip`` sets ``kind`` ("video"/"images"), ``frame_indices`` (index
        of each frame in the source before stride/max_frames), ``n_source_frames`` (None if
        unknown), ``source_size`` (W,H before resizing), ``primaries`` (``{"name", "how"}``: the
        colour primaries of the frames' RGB, ffmpeg's name, and whether the input said so or it is
        assumed), ``notes`` (lines said once when a run starts: a dropped alpha channel, a
        variable frame rate, sound dropped), ``paths`` for images; for videos ``video`` (what the
        input's header says, :func:`layercam.io.video.parse_header`) and ``audio`` (the sound the
        videos written carry over, :func:`audio_plan`; None without).
    """

    frames: np.ndarray
    source: str
    names: list[str]
    fps: float = 24.0
    bit_depth: int = 8
    exif_exposures: list[float | None] | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        f = np.asarray(self.frames)
        if f.ndim != 4 or f.shape[3] != 3:
            raise ValueError(f"Clip.frames must be (T,H,W,3), got shape {f.shape}")
        if f.shape[0] < 1:
            raise ValueError("Clip needs at least one frame")
        if f.dtype != np.float32:
            f = f.astype(np.float32)
        self.frames = f
        self.names = [str(n) for n in self.names]
        if len(self.names) != f.shape[0]:
            raise ValueError(f"Clip has {f.shape[0]} frames but {len(self.names)} names")
        if self.exif_exposures is not None and len(self.exif_exposures) != f.shape[0]:
            raise ValueError(
                f"Clip has {f.shape[0]} frames but {len(self.exif_exposures)} EXIF exposures"
            )
        self.fps = float(self.fps)

    @property
    def T(self) -> int:  # noqa: N802 - conventional shape name
        return int(self.frames.shape[0])

    @property
    def H(self) -> int:  # noqa: N802
        return int(self.frames.shape[1])

    @property
    def W(self) -> int:  # noqa: N802
        return int(self.frames.shape[2])

    def fingerprint(self) -> str:
        """SHA-1 hex of the shape and the float16-quantised frames: a cache key for this content."""
        return fingerprint(self.frames)

    def __repr__(self) -> str:
        return (
            f"Clip(source={self.source!r}, T={self.T}, H={self.H}, W={self.W}, "
            f"fps={self.fps:g}, bit_depth={self.bit_depth})"
        )


def fingerprint(frames: np.ndarray) -> str:
    """SHA-1 hex of an array of frames ``(T, ...)``: its shape and its values quantised to float16,
    one frame at a time (no float16 copy of the whole clip): a cache key for this content (the
    clip's frames, the user's masks)."""
    h = hashlib.sha1()
    h.update(repr(tuple(frames.shape)).encode())
    for f in frames:
        h.update(np.ascontiguousarray(f, dtype=np.float16).tobytes())
    return h.hexdigest()


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


def _target_size(rs, w: int, h: int) -> tuple[int, int]:
    if rs is None:
        return (w, h)
    kind, val = rs
    if kind == "size":
        return val  # type: ignore[return-value]
    return (max(1, int(round(w * val))), max(1, int(round(h * val))))


def _resize(img: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    import cv2

    w, h = size
    if (img.shape[1], img.shape[0]) == (w, h):
        return img
    down = w * h < img.shape[0] * img.shape[1]
    interp = cv2.INTER_AREA if down else cv2.INTER_LINEAR
    out = cv2.resize(img, (w, h), interpolation=interp)
    return np.clip(out, 0.0, 1.0).astype(np.float32, copy=False)


def _check_count(name: str, value, minimum: int) -> None:
    if value is None and name == "max_frames":
        return
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise LayercamError(f"{name} must be an integer >= {minimum}, got {value!r}")


def _list_folder(folder: Path) -> list[Path]:
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


def _expand_inputs(inputs) -> tuple[str, list[Path] | Path]:
    """Return ("video", path) or ("images", [paths]) for the user's input."""
    if isinstance(inputs, (str, os.PathLike)):
        s = os.fspath(inputs)
        if isinstance(s, str) and s.startswith("synthetic:"):
            raise LayercamError(f"{s!r} is a synthetic clip: build it with layercam.synth, not load_clip")
        p = Path(s).expanduser()
        if p.is_dir():
            return ("images", _list_folder(p))
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
            return _expand_inputs(inputs[0])
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


def _unique_names(paths: list[Path]) -> list[str]:
    names, seen = [], {}
    for p in paths:
        stem = p.stem
        n = seen.get(stem, 0)
        seen[stem] = n + 1
        names.append(stem if n == 0 else f"{stem}_{n}")
    return names


def load_clip(
    inputs: str | os.PathLike | list,
    max_frames: int | None = None,
    stride: int = 1,
    resize: str | float | None = None,
) -> Clip:
    """Load a video file, a folder of images or a list of image files as a ``Clip``.

    inputs: video (mp4/mov/avi/mkv/...), folder (image files sorted naturally by name; other
        files ignored), list of image paths (kept in the given order) or an unexpanded glob.
    stride: keep every K-th frame; then max_frames keeps the first N of those.
    resize: None, a factor (``0.5`` or ``"0.5"``) or ``"WxH"``; INTER_AREA when shrinking.
    Images of differing sizes raise ``LayercamError`` naming the file unless resize is "WxH".
    Every user-input problem raises ``LayercamError`` with a one-line message.
    """
    _check_count("stride", stride, 1)
    _check_count("max_frames", max_frames, 1)
    rs = parse_resize(resize)
    kind, what = _expand_inputs(inputs)
    source = os.fspath(inputs) if isinstance(inputs, (str, os.PathLike)) else ",".join(
        os.fspath(p) for p in inputs
    )

    if kind == "video":
        assert isinstance(what, Path)
        u8, fps, info = read_video(what, max_frames=max_frames, stride=stride, with_info=True)
        t, h, w, _ = u8.shape
        tw, th = _target_size(rs, w, h)
        frames = np.empty((t, th, tw, 3), np.float32)
        for i in range(t):
            frames[i] = _resize(u8[i].astype(np.float32) / 255.0, (tw, th))
        idx = [i * stride for i in range(t)]
        audio, notes = audio_plan(what, info, t, fps, stride, max_frames)
        return Clip(
            frames=frames,
            source=source,
            names=[f"{i:05d}" for i in idx],
            fps=fps,
            bit_depth=8,
            exif_exposures=None,
            meta={
                "kind": "video",
                "frame_indices": idx,
                "n_source_frames": None,
                "source_size": (w, h),
                "video": info,
                "primaries": primaries_of(info.get("primaries")),
                "audio": audio,
                "notes": notes,
            },
        )

    assert isinstance(what, list)
    all_paths = what
    idx = list(range(0, len(all_paths), stride))
    if max_frames is not None:
        idx = idx[:max_frames]
    paths = [all_paths[i] for i in idx]
    frames, depths, alphas = None, [], []
    size0 = None
    target = None
    for i, p in enumerate(paths):
        img, depth, alpha = read_image(p, return_bit_depth=True, return_alpha=True)
        if alpha is not None:
            alphas.append(alpha)
        h, w = img.shape[:2]
        if size0 is None:
            size0 = (w, h)
            target = _target_size(rs, w, h)
        elif (w, h) != size0 and not (rs is not None and rs[0] == "size"):
            raise LayercamError(
                f"{p.name} is {w}x{h} but {paths[0].name} is {size0[0]}x{size0[1]}; "
                "give --resize WxH to bring all frames to one size"
            )
        if frames is None:  # filled frame by frame: no second copy of the clip (1080p x 48: 1.2 GB)
            frames = np.empty((len(paths), target[1], target[0], 3), np.float32)
        frames[i] = _resize(img, target)
        depths.append(depth)
    exif = [read_exif_exposure(p) if p.suffix.lower() in _EXIF_SUFFIXES else None for p in paths]
    return Clip(
        frames=frames,
        source=source,
        names=_unique_names(paths),
        fps=24.0,
        bit_depth=max(depths),
        exif_exposures=exif,
        meta={
            "kind": "images",
            "frame_indices": idx,
            "n_source_frames": len(all_paths),
            "source_size": size0,
            "paths": [str(p) for p in paths],
            "primaries": primaries_of(None),
            "notes": [_alpha_note(alphas, len(paths))] if alphas else [],
        },
    )


def primaries_of(tag: str | None) -> dict:
    """The colour primaries of a clip's RGB: the input's tag where it names primaries
    :mod:`layercam.bt2100` knows, else BT.709 / sRGB (what 8-bit video and images without tags
    are), said as assumed."""
    from layercam.bt2100 import PRIMARIES

    if tag in PRIMARIES:
        return {"name": tag, "how": "tagged in the input"}
    said = f" (the input says {tag}, not known here)" if tag else ""
    return {"name": "bt709", "how": f"assumed: BT.709 / sRGB, as untagged 8-bit video and images are{said}"}


def audio_plan(path: Path, info: dict, n: int, fps: float, stride: int, max_frames: int | None) -> tuple[dict | None, list[str]]:
    """The sound the videos written from a clip of ``n`` frames carry over from the input ``path``
    (``{"path", "codec", "duration"}``: the input's first audio stream from its start, cut at
    ``duration`` seconds when ``--max-frames`` ended the clip early; None without sound or with a
    stride, whose frames no longer keep the input's time) and the lines a run says about timing
    and sound (a variable frame rate, sound dropped)."""
    notes = []
    if info.get("variable"):
        notes.append(f"{path.name} has a variable frame rate ({info['fps']:g} fps on average): its frames are taken at a constant "
                     f"{fps:g} fps (ffmpeg repeats or drops a frame where the timing needs it, so the sound stays in step), and every video is written at {fps:g} fps")
    if not info.get("audio"):
        return None, notes
    if stride > 1:
        notes.append(f"--stride {stride}: the sound of {path.name} is dropped (every {stride}th frame played at {fps:g} fps no longer keeps the input's time)")
        return None, notes
    span = n / fps
    dur = info.get("duration")
    cut = max_frames is not None and n == max_frames and (dur is None or span < dur - 0.5 / fps)
    return {"path": str(path.resolve()), "codec": info["audio"], "duration": span if cut else None}, notes


def _alpha_note(transparent: list[float], n: int) -> str:
    """One line for frames whose alpha channel is dropped (layercam reads RGB)."""
    part = f"{max(transparent):.0%} of the pixels transparent at most" if max(transparent) > 0 else "fully opaque"
    return f"{len(transparent)} of {n} frames have an alpha channel ({part}): alpha is dropped, the RGB values are used as they are"
