"""A clip: the frames of one input (video file, folder of images, list of images) as
``(T,H,W,3)`` RGB in [0,1] (:class:`layercam.io.frames.Frames`: stored compactly, in memory or in a
file on disk, read as float32 a frame or a window at a time), with per-frame names, fps, bit depth
and EXIF exposures. ``load_clip`` decodes frame by frame into a file (the run's cache, or an
unlinked temporary file), so that no stage ever holds the whole clip.
"""

from __future__ import annotations

import glob
import hashlib
import os
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from layercam.errors import LayercamError
from layercam.interrupts import reached
from layercam.io.frames import DiskArray, Frames
from layercam.io.images import IMAGE_SUFFIXES, read_exif_exposure, read_image
from layercam.io.video import VIDEO_SUFFIXES, iter_video, probe_video

__all__ = ["Clip", "load_clip", "probe_clip", "parse_resize", "natural_key"]

FRAMES_VERSION = 2  # the layout of a decoded clip in the cache (frames-<key>/frames.raw + clip.json)

_EXIF_SUFFIXES = (".jpg", ".jpeg", ".tif", ".tiff")
_GLOB_CHARS = re.compile(r"[*?\[]")


@dataclass
class Clip:
    """Frames of one input and what is known about them.

    frames: ``(T,H,W,3)`` RGB in [0,1], a :class:`~layercam.io.frames.Frames`: ``frames[t]``
        ``(H,W,3)`` and ``frames[t0:t1]`` ``(n,H,W,3)`` are float32 copies of those frames only,
        ``for f in frames`` gives one frame at a time, ``frames.shape`` is ``(T,H,W,3)`` and
        ``np.asarray(frames)`` is the whole clip in float32 (only for clips known to be short).
        An ndarray given here is kept in memory as float32; ``load_clip`` stores the frames on
        disk as uint8 (uint16 for 16-bit sources, float32 for float images).
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

    frames: Frames
    source: str
    names: list[str]
    fps: float = 24.0
    bit_depth: int = 8
    exif_exposures: list[float | None] | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.frames, Frames):
            f = np.asarray(self.frames)
            if f.ndim != 4 or f.shape[3] != 3:
                raise ValueError(f"Clip.frames must be (T,H,W,3), got shape {f.shape}")
            self.frames = Frames(f.astype(np.float32, copy=False))
        f = self.frames
        if f.shape[0] < 1:
            raise ValueError("Clip needs at least one frame")
        self._fingerprint = self.meta.pop("_fingerprint", None) if isinstance(self.meta, dict) else None
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
        """SHA-1 hex of the shape and the float16-quantised frames: a cache key for this content
        (computed once: the frames do not change)."""
        if self._fingerprint is None:
            self._fingerprint = fingerprint(self.frames)
        return self._fingerprint

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


def _source_key(kind: str, what, stride: int, max_frames: int | None, rs) -> str:
    """What names a decoded clip in the cache: the files (path, size, modification time), the
    frames taken and the resize."""
    files = [what] if kind == "video" else list(what)
    ident = []
    for p in files:
        st = Path(p).stat()
        ident.append([str(Path(p).resolve()), st.st_size, st.st_mtime_ns])
    blob = repr((FRAMES_VERSION, kind, ident, stride, max_frames, rs)).encode()
    return hashlib.sha1(blob).hexdigest()[:12]


def probe_clip(
    inputs: str | os.PathLike | list,
    max_frames: int | None = None,
    stride: int = 1,
    resize: str | float | None = None,
) -> dict:
    """What :func:`load_clip` would give, without decoding the clip: ``{"kind", "frames", "width",
    "height", "source_size", "bit_depth"}``. ``frames`` is exact for images and, for a video, the
    count its container states (duration times rate; None when it states none); ``bit_depth`` is
    the first image's (8 for a video). Reads a video's header and the first image only, so that a
    run can say what it will cost (:mod:`layercam.estimate`) before anything is decoded. Bad input
    raises ``LayercamError`` as ``load_clip`` does."""
    _check_count("stride", stride, 1)
    _check_count("max_frames", max_frames, 1)
    rs = parse_resize(resize)
    kind, what = _expand_inputs(inputs)
    if kind == "video":
        info = probe_video(what)
        w, h = info["size"]
        n = info["frames"]
        n = None if n is None else -(-n // stride)
        depth = 8
    else:
        n = len(range(0, len(what), stride))
        img, depth = read_image(what[0], return_bit_depth=True)
        h, w = img.shape[:2]
    if max_frames is not None:
        n = max_frames if n is None else min(n, max_frames)
    tw, th = _target_size(rs, w, h)
    return {"kind": kind, "frames": n, "width": tw, "height": th, "source_size": (w, h), "bit_depth": depth}


_STORE = {8: np.uint8, 16: np.uint16, 32: np.float32}


def _store_dtype(depth: int):
    return _STORE.get(depth, np.float32 if depth > 16 else np.uint16)


def _quantise(img: np.ndarray, dtype) -> np.ndarray:
    """A float32 frame in [0,1] as stored: ``round(v * 255)`` (uint8), ``round(v * 65535)``
    (uint16) or as it is (float32)."""
    if dtype == np.float32:
        return np.asarray(img, np.float32)
    top = 255.0 if dtype == np.uint8 else 65535.0
    return np.rint(np.clip(img, 0.0, 1.0) * np.float32(top)).astype(dtype)


class _Sink:
    """Frames appended one at a time to a raw file: in ``folder`` as ``frames.raw``, or an unlinked
    temporary file when ``folder`` is None."""

    def __init__(self, folder: Path | None, dtype):
        import tempfile

        self.dtype, self.shape, self.n = np.dtype(dtype), None, 0
        if folder is None:
            self.fd, name = tempfile.mkstemp(prefix="layercam-frames-", suffix=".raw")
            os.unlink(name)
            self.path = Path(name)
        else:
            self.path = folder / "frames.raw"
            self.fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_TRUNC, 0o644)

    def add(self, frame: np.ndarray) -> None:
        f = np.ascontiguousarray(frame, self.dtype)
        if self.shape is None:
            self.shape = f.shape
        buf = memoryview(f.reshape(-1).view(np.uint8))
        done = 0
        while done < len(buf):
            done += os.write(self.fd, buf[done:])
        self.n += 1

    def finish(self) -> DiskArray:
        return DiskArray(self.path, self.dtype, (self.n, *self.shape), _fd=self.fd)

    def abandon(self) -> None:
        os.close(self.fd)


def _cached_clip(folder: Path) -> Clip | None:
    """The clip a finished decode left in ``folder`` (``clip.json`` written last), else None."""
    import json

    try:
        info = json.loads((folder / "clip.json").read_text())
        if info.get("version") != FRAMES_VERSION:
            return None
        raw = DiskArray(folder / "frames.raw", info["dtype"], info["shape"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    meta = dict(info["meta"], frames_cache=str(folder), _fingerprint=info["fingerprint"])
    if meta.get("source_size") is not None:
        meta["source_size"] = tuple(meta["source_size"])
    return Clip(frames=Frames(raw), source=info["source"], names=info["names"], fps=info["fps"], bit_depth=info["bit_depth"],
                exif_exposures=info["exif_exposures"], meta=meta)


def load_clip(
    inputs: str | os.PathLike | list,
    max_frames: int | None = None,
    stride: int = 1,
    resize: str | float | None = None,
    cache: str | os.PathLike | None = None,
) -> Clip:
    """Load a video file, a folder of images or a list of image files as a ``Clip``.

    inputs: video (mp4/mov/avi/mkv/...), folder (image files sorted naturally by name; other
        files ignored), list of image paths (kept in the given order) or an unexpanded glob.
    stride: keep every K-th frame; then max_frames keeps the first N of those.
    resize: None, a factor (``0.5`` or ``"0.5"``) or ``"WxH"``; INTER_AREA when shrinking.
    cache: a folder (a run's ``cache/``) where the decoded frames are kept as
        ``frames-<key>/frames.raw`` and ``clip.json``, the key naming the files (path, size,
        modification time), stride, max_frames and resize: the same call again maps them without
        decoding. None: an unlinked temporary file that disappears with the clip.
    Frames are decoded one at a time (video: the ffmpeg stream) and appended to the file as uint8
    (uint16 for 16-bit images, float32 for float images); memory is that of one frame, whatever
    the clip's length. A resized frame is rounded to its storage (half a level of 8 bits at most).
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
    folder = None
    if cache is not None:
        from layercam.io.atomic import ensure_writable_dir

        key = _source_key(kind, what, stride, max_frames, rs)
        folder = Path(cache) / f"frames-{key}"
        found = _cached_clip(folder)
        if found is not None:
            found.source = source
            return found
        ensure_writable_dir(Path(cache))
        for stale in Path(cache).glob(f".frames-{key}.partial-*"):  # left by a decode that was killed
            if not _alive(stale.name.rsplit("-", 1)[-1]):
                shutil.rmtree(stale, ignore_errors=True)
        partial = Path(cache) / f".frames-{key}.partial-{os.getpid()}"
        shutil.rmtree(partial, ignore_errors=True)
        partial.mkdir()
    try:
        clip = (_decode_video if kind == "video" else _decode_images)(what, source, max_frames, stride, rs, None if folder is None else partial)
        if folder is not None:
            _keep(clip, partial, folder)
            clip = _cached_clip(folder)
            if clip is None:
                raise LayercamError(f"cannot read back the decoded frames in {folder}")
            clip.source = source
    finally:
        if folder is not None and partial.exists():
            shutil.rmtree(partial, ignore_errors=True)
    return clip


def _alive(pid: str) -> bool:
    """Whether the process ``pid`` (text) still runs (a decode of another process in progress)."""
    try:
        os.kill(int(pid), 0)
    except (ValueError, ProcessLookupError):
        return False
    except PermissionError:
        return True
    return True


def _keep(clip: Clip, partial: Path, folder: Path) -> None:
    """``clip.json`` beside ``frames.raw`` in ``partial``, then ``partial`` renamed to ``folder``
    (a decode another process finished first is kept instead)."""
    import json

    raw = clip.frames.raw
    info = {"version": FRAMES_VERSION, "dtype": raw.dtype.str, "shape": list(raw.shape), "source": clip.source, "names": clip.names,
            "fps": clip.fps, "bit_depth": clip.bit_depth, "exif_exposures": clip.exif_exposures, "fingerprint": clip.fingerprint(),
            "meta": {k: (list(v) if isinstance(v, tuple) else v) for k, v in clip.meta.items()}}
    os.fsync(raw._fd)
    (partial / ".made").touch()  # decoded by this command: removed again if it fails before its stages (cli.before_stages)
    (partial / "clip.json").write_text(json.dumps(info))
    raw.close()
    try:
        os.rename(partial, folder)
    except OSError:
        if _cached_clip(folder) is None:  # not a finished decode of another process: ours replaces it
            shutil.rmtree(folder, ignore_errors=True)
            os.rename(partial, folder)


def _decode_video(path: Path, source: str, max_frames, stride: int, rs, folder: Path | None) -> Clip:
    sink, info = _Sink(folder, np.uint8), {}
    try:
        for frame in iter_video(path, max_frames=max_frames, stride=stride, info=info):
            reached("decode", sink.n)
            if sink.n == 0:
                w, h = info["size"]
                tw, th = _target_size(rs, w, h)
            if (tw, th) == (w, h):
                sink.add(frame)
            else:
                sink.add(_quantise(_resize(frame.astype(np.float32) / 255.0, (tw, th)), np.uint8))
    except BaseException:
        sink.abandon()
        raise
    idx = [i * stride for i in range(sink.n)]
    header = info["header"]
    audio, notes = audio_plan(path, header, sink.n, info["fps"], stride, max_frames)
    return Clip(
        frames=Frames(sink.finish()),
        source=source,
        names=[f"{i:05d}" for i in idx],
        fps=info["fps"],
        bit_depth=8,
        exif_exposures=None,
        meta={"kind": "video", "frame_indices": idx, "n_source_frames": None, "source_size": info["size"], "video": header,
              "primaries": primaries_of(header.get("primaries")), "audio": audio, "notes": notes},
    )


def _decode_images(all_paths: list[Path], source: str, max_frames, stride: int, rs, folder: Path | None, depth: int = 8) -> Clip:
    idx = list(range(0, len(all_paths), stride))
    if max_frames is not None:
        idx = idx[:max_frames]
    paths = [all_paths[i] for i in idx]
    dtype = _store_dtype(depth)
    sink = _Sink(folder, dtype)
    depths, alphas = [], []
    size0 = target = None
    try:
        for i, p in enumerate(paths):
            reached("decode", i)
            img, d, alpha = read_image(p, return_bit_depth=True, return_alpha=True)
            if d > depth and _store_dtype(d) != dtype:  # a deeper frame than the first: again, stored as deep as it
                sink.abandon()
                return _decode_images(all_paths, source, max_frames, stride, rs, folder, d)
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
            sink.add(_quantise(_resize(img, target), dtype))
            depths.append(d)
    except BaseException:
        sink.abandon()
        raise
    exif = [read_exif_exposure(p) if p.suffix.lower() in _EXIF_SUFFIXES else None for p in paths]
    return Clip(
        frames=Frames(sink.finish()),
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
