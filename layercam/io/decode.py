"""Decoding a clip once into the run's cache: frames written a frame at a time to a memory-mapped
``frames.raw`` (8 bits a channel, 16 for 16-bit input) beside ``clip.json``, in a partial folder renamed
when complete; a second command on the same input maps them without decoding (``load_clip``)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np

from layercam.core.errors import LayercamError
from layercam.core.interrupts import reached
from layercam.io.frames import DiskArray, Frames
from layercam.io.lock import pid_alive
from layercam.io.images import read_exif_exposure, read_image
from layercam.io.video import iter_video, probe_video
from layercam.io.clip import Clip
from layercam.io.inputs import (FRAMES_VERSION, EXIF_SUFFIXES, alpha_note, audio_plan, check_count,
                                expand_inputs, parse_resize, primaries_of, resize, source_key,
                                 target_size, unique_names)


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
    run can say what it will cost (:mod:`layercam.engine.estimate`) before anything is decoded. Bad input
    raises ``LayercamError`` as ``load_clip`` does."""
    check_count("stride", stride, 1)
    check_count("max_frames", max_frames, 1)
    rs = parse_resize(resize)
    kind, what = expand_inputs(inputs)
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
    tw, th = target_size(rs, w, h)
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
    return Clip(frames=Frames(raw), source=info["source"], names=info["names"], fps=info["fps"],
                bit_depth=info["bit_depth"],
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
    check_count("stride", stride, 1)
    check_count("max_frames", max_frames, 1)
    rs = parse_resize(resize)
    kind, what = expand_inputs(inputs)
    source = os.fspath(inputs) if isinstance(inputs, (str, os.PathLike)) else ",".join(
        os.fspath(p) for p in inputs
    )
    folder = None
    if cache is not None:
        from layercam.io.atomic import ensure_writable_dir

        key = source_key(kind, what, stride, max_frames, rs)
        folder = Path(cache) / f"frames-{key}"
        found = _cached_clip(folder)
        if found is not None:
            found.source = source
            return found
        ensure_writable_dir(Path(cache))
        for stale in Path(cache).glob(f".frames-{key}.partial-*"):  # left by a decode that was killed
            if not pid_alive(_pid(stale.name.rsplit("-", 1)[-1])):
                shutil.rmtree(stale, ignore_errors=True)
        partial = Path(cache) / f".frames-{key}.partial-{os.getpid()}"
        shutil.rmtree(partial, ignore_errors=True)
        partial.mkdir()
    try:
        clip = (_decode_video if kind == "video" else _decode_images)(what, source, max_frames,
            stride, rs, None if folder is None else partial)
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


def _keep(clip: Clip, partial: Path, folder: Path) -> None:
    """``clip.json`` beside ``frames.raw`` in ``partial``, then ``partial`` renamed to ``folder``
    (a decode another process finished first is kept instead)."""
    import json

    raw = clip.frames.raw
    info = {"version": FRAMES_VERSION, "dtype": raw.dtype.str, "shape": list(raw.shape),
            "source": clip.source, "names": clip.names,
            "fps": clip.fps, "bit_depth": clip.bit_depth, "exif_exposures": clip.exif_exposures,
            "fingerprint": clip.fingerprint(),
            "meta": {k: (list(v) if isinstance(v, tuple) else v) for k, v in clip.meta.items()}}
    os.fsync(raw._fd)
    (partial / ".made").touch()  # decoded by this command: removed again if it fails before its
                                 # stages (cli.before_stages)
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
                tw, th = target_size(rs, w, h)
            if (tw, th) == (w, h):
                sink.add(frame)
            else:
                sink.add(_quantise(resize(frame.astype(np.float32) / 255.0, (tw, th)), np.uint8))
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
        meta={"kind": "video", "frame_indices": idx, "n_source_frames": None,
              "source_size": info["size"], "video": header,
              "primaries": primaries_of(header.get("primaries")), "audio": audio, "notes": notes},
    )


def _decode_images(all_paths: list[Path], source: str, max_frames, stride: int, rs,
                   folder: Path | None, depth: int = 8) -> Clip:
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
                target = target_size(rs, w, h)
            elif (w, h) != size0 and not (rs is not None and rs[0] == "size"):
                raise LayercamError(
                    f"{p.name} is {w}x{h} but {paths[0].name} is {size0[0]}x{size0[1]}; "
                    "give --resize WxH to bring all frames to one size"
                )
            sink.add(_quantise(resize(img, target), dtype))
            depths.append(d)
    except BaseException:
        sink.abandon()
        raise
    exif = [read_exif_exposure(p) if p.suffix.lower() in EXIF_SUFFIXES else None for p in paths]
    return Clip(
        frames=Frames(sink.finish()),
        source=source,
        names=unique_names(paths),
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
            "notes": [alpha_note(alphas, len(paths))] if alphas else [],
        },
    )


def _pid(text: str) -> int:
    """A partial folder's pid suffix as a number (-1 when it is not one)."""
    try:
        return int(text)
    except ValueError:
        return -1
