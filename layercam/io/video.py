"""Video files: decode to uint8 frames ``(T,H,W,3)`` and encode H.264 mp4, through the ffmpeg
binary bundled with imageio-ffmpeg (works offline). Imported lazily inside the functions.

What the input's header says (frame rate, variable rate, duration, sound, colour primaries) comes
with the frames (``read_video(..., with_info=True)``, :func:`layercam.io.ffmpeg.parse_header`); the videos
written keep the input's frame rate as a fraction (:func:`layercam.io.ffmpeg.rate_text`: 30000/1001,
not 29.97) and carry its sound
over (:func:`mux_audio`, ``VideoWriter(audio=...)``).
"""

from __future__ import annotations

import os
import re
import subprocess
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from layercam.core.errors import LayercamError
from layercam.io.ffmpeg import ffmpeg_exe, last_line, ntsc, parse_header, rate_text

__all__ = ["VideoWriter", "VIDEO_SUFFIXES", "iter_video", "probe_video", "read_video",
           "write_video", "mux_audio", "mp4_complete"]

VIDEO_SUFFIXES: tuple[str, ...] = (".mp4", ".mov", ".avi", ".mkv", ".m4v", ".webm", ".gif")


def _check_int(name: str, value, minimum: int) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise LayercamError(f"{name} must be an integer, got {value!r}")
    if value < minimum:
        raise LayercamError(f"{name} must be >= {minimum}, got {value}")


# the output stream's whole line (its newline too: on a loaded machine the log was read while ffmpeg
# had written the line up to the size and not yet the rate, and the clip took 24 fps)
_OUT_STREAM = re.compile(r"Output #0.*?Stream #0:0.*?: Video: rawvideo[^\n]*?, (\d+)x(\d+)([^\n]*)\n", re.S)


_DURATION = re.compile(r"Duration: (\d+):(\d+):([\d.]+)")


def iter_video(path: str | os.PathLike, max_frames: int | None = None, stride: int = 1,
               info: dict | None = None) -> Iterator[np.ndarray]:
    """Decode a video file frame by frame: yields uint8 RGB ``(H, W, 3)`` frames, one in memory at
    a time. ``stride`` keeps every K-th frame (0, K, 2K, ...), then ``max_frames`` keeps the first
    N of those; decoding stops as soon as N are given. ``info``, when given, is filled before the
    first frame with ``size`` ``(W, H)``, ``fps`` and ``frames`` (the stream's frame count from its
    duration and rate, None when ffmpeg does not say) and ``header`` (:func:`parse_header` of the
    input). The frames come at a constant rate ``fps``: a variable-rate input is decoded at the rate
    ffmpeg guesses for it (its ``tbr``), repeating or dropping a frame where the timing needs it.
    Raises ``LayercamError`` for a missing, corrupt or non-video file, or one with no frames. Runs
    imageio-ffmpeg's bundled ffmpeg binary directly (all pipes are closed when the generator ends or is closed)."""
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"read_video expects a path, got {type(path).__name__}")
    _check_int("stride", stride, 1)
    if max_frames is not None:
        _check_int("max_frames", max_frames, 1)
    p = Path(path).expanduser()
    if not p.exists():
        raise LayercamError(f"video not found: {p}")
    if p.is_dir():
        raise LayercamError(f"expected a video file, got a folder: {p}")

    cmd = [
        ffmpeg_exe(), "-nostdin", "-hide_banner", "-nostats",
        "-i", str(p), "-map", "0:v:0", "-f", "rawvideo", "-pix_fmt", "rgb24", "-",
    ]  # fmt: skip
    given = 0
    # ffmpeg writes its log through the file description it inherits, whose offset it shares with
    # ours: seeking it to read would make ffmpeg overwrite the header we wait for (seen as a flaky
    # "not a video" on a loaded machine). So the log is written in append mode and read apart.
    with tempfile.NamedTemporaryFile(mode="ab") as sink, open(sink.name, "rb") as log:
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=sink)
        try:
            # The output stream header is logged before the first frame reaches the pipe.
            deadline = time.monotonic() + 60.0
            while True:
                log.seek(0)
                text = log.read().decode("utf-8", "replace")
                m = _OUT_STREAM.search(text)
                if m or proc.poll() is not None or time.monotonic() > deadline:
                    break
                time.sleep(0.005)
            if not m:
                log.seek(0)
                text = log.read().decode("utf-8", "replace")
                m = _OUT_STREAM.search(text)
            if not m:
                raise LayercamError(
                    f"cannot read video {p}: not a video or corrupt ({last_line(text)})"
                )
            w, h = int(m.group(1)), int(m.group(2))
            rate = re.search(r"([\d.]+) (?:fps|tbr)", m.group(3))
            fps = ntsc(float(rate.group(1))) if rate else 24.0
            if not np.isfinite(fps) or fps <= 0:
                fps = 24.0
            if info is not None:
                dur = _DURATION.search(text)
                secs = int(dur.group(1)) * 3600 + int(dur.group(2)) * 60 + float(dur.group(3)) if dur else None
                info.update(size=(w, h), fps=fps, frames=int(round(secs * fps)) if secs else None,
                            header=parse_header(text))
            nbytes = w * h * 3
            assert proc.stdout is not None
            i = 0
            while max_frames is None or given < max_frames:
                buf = proc.stdout.read(nbytes)
                if len(buf) < nbytes:
                    break  # end of stream (or a truncated last frame)
                if i % stride == 0:
                    given += 1
                    yield np.frombuffer(buf, dtype=np.uint8).reshape(h, w, 3)
                i += 1
        finally:
            if proc.stdout is not None:
                proc.stdout.close()
            if proc.poll() is None:
                proc.kill()
            proc.wait()
        if not given:
            log.seek(0)
            text = log.read().decode("utf-8", "replace")
            raise LayercamError(f"video {p} has no decodable frames ({last_line(text)})")


def probe_video(path: str | os.PathLike) -> dict:
    """What :func:`iter_video` learns before the first frame, without decoding the clip:
    ``{"size": (W, H), "fps": float, "frames": int | None, "header": dict}``."""
    info: dict = {}
    gen = iter_video(path, max_frames=1, info=info)
    try:
        next(gen)
    finally:
        gen.close()
    return info


def read_video(path: str | os.PathLike, max_frames: int | None = None, stride: int = 1, with_info: bool = False):
    """Decode a video file into ``(frames, fps)`` (``(frames, fps, info)`` with ``with_info``):
    ``frames`` uint8 RGB ``(T, H, W, 3)``, the whole clip in memory (:func:`iter_video` gives one
    frame at a time), at a constant rate ``fps``; ``info``: :func:`parse_header` of the input.
    ``stride`` and ``max_frames`` as there. Raises ``LayercamError`` for a missing, corrupt or
    non-video file, or one with no frames."""
    info: dict = {}
    frames = np.stack(list(iter_video(path, max_frames, stride, info)), axis=0)
    if with_info:
        return frames, info["fps"], info["header"]
    return frames, info["fps"]


def _to_uint8(frames: np.ndarray) -> np.ndarray:
    if frames.dtype == np.uint8:
        return frames
    f = frames.astype(np.float32, copy=False)
    if not np.all(np.isfinite(f)):
        raise ValueError("write_video got non-finite values")
    return np.round(np.clip(f, 0.0, 1.0) * 255.0).astype(np.uint8)


class VideoWriter:
    """An H.264 (libx264, yuv420p) mp4 written one frame at a time, so that its memory is one
    frame's whatever the clip's length; the file appears under ``path`` (atomically) when the
    ``with`` block ends without an error, and no partial file is left when it ends with one.

    >>> with VideoWriter(path, fps=24) as vw:      # doctest: +SKIP
    ...     for frame in frames:
    ...         vw.add(frame)

    Frames are ``(H,W,3)`` RGB (float in [0,1], clipped, or uint8) or ``(H,W)`` grey, all of one
    size; odd sizes are padded to even by repeating the last row/column. ``crf`` is x264's quality.
    ``audio`` (``{"path", "duration"}``, :func:`mux_audio`): sound carried over from that file when
    the video is complete; ``audio_info`` then says what became of it.
    """

    def __init__(self, path: str | os.PathLike, fps: float = 24.0, crf: int = 18, audio: dict | None = None):
        fps = float(fps)
        if not np.isfinite(fps) or fps <= 0:
            raise ValueError(f"fps must be positive, got {fps}")
        self.path, self.fps, self.crf, self.audio = Path(path), fps, int(crf), audio
        self._gen, self._tmp, self._size, self.frames = None, None, None, 0
        self.audio_info: dict | None = None

    def __enter__(self) -> "VideoWriter":
        return self

    def add(self, frame: np.ndarray) -> None:
        f = np.asarray(frame)
        if f.ndim == 2:
            f = np.repeat(f[..., None], 3, axis=2)
        if f.ndim != 3 or f.shape[2] != 3 or f.shape[0] == 0 or f.shape[1] == 0:
            raise ValueError(f"a video frame is (H,W,3) or (H,W), got shape {np.asarray(frame).shape}")
        u8 = _to_uint8(f)
        h, w = u8.shape[:2]
        if self._gen is None:
            self._start(h, w)
        elif (h, w) != self._size:
            raise ValueError(f"video frames must all be {self._size[1]}x{self._size[0]}, got {w}x{h}")
        if h % 2 or w % 2:
            u8 = np.pad(u8, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
        try:
            self._gen.send(np.ascontiguousarray(u8))
        except (OSError, RuntimeError) as e:
            raise LayercamError(f"cannot write video {self.path}: {str(e).strip()[:160]}") from None
        self.frames += 1

    def _start(self, h: int, w: int) -> None:
        import imageio_ffmpeg

        from layercam.io.atomic import ensure_writable_dir, temp_name

        ensure_writable_dir(self.path.parent)
        self._size, self._tmp = (h, w), temp_name(self.path)
        from fractions import Fraction

        self._gen = imageio_ffmpeg.write_frames(
            str(self._tmp), (w + w % 2, h + h % 2), fps=Fraction(rate_text(self.fps)),
            codec="libx264", quality=None, macro_block_size=2,
            pix_fmt_out="yuv420p", ffmpeg_log_level="error",
            output_params=["-crf", str(self.crf), "-preset", "medium", "-movflags", "+faststart"],
        )
        self._gen.send(None)

    def __exit__(self, exc_type, exc, tb) -> None:
        gen, tmp = self._gen, self._tmp
        self._gen = None
        if gen is not None:
            try:
                gen.close()
            except (OSError, RuntimeError) as e:
                if exc_type is None:
                    tmp.unlink(missing_ok=True)
                    raise LayercamError(f"cannot write video {self.path}: {str(e).strip()[:160]}") from None
        if exc_type is not None:
            if tmp is not None:
                tmp.unlink(missing_ok=True)
            return
        if self.frames == 0:
            raise ValueError("write_video got an empty clip")
        if not mp4_complete(tmp):  # ffmpeg's failure (a full disk) is not raised by imageio-ffmpeg
            tmp.unlink(missing_ok=True)
            raise LayercamError(f"cannot write video {self.path}: ffmpeg left an incomplete file (is the disk full?)")
        self.audio_info = finish_with_audio(tmp, self.path, self.audio)


def finish_with_audio(tmp: Path, path: Path, audio: dict | None) -> dict | None:
    """The complete video ``tmp`` becomes ``path`` (a rename), with ``audio``'s sound carried over
    first when given (:func:`mux_audio`). Returns what became of the sound (None without)."""
    from layercam.io.atomic import temp_name

    info = None
    if audio:
        out = temp_name(path)
        try:
            info = mux_audio(tmp, audio, out)
        except BaseException:
            out.unlink(missing_ok=True)
            tmp.unlink(missing_ok=True)
            raise
        if info["kept"]:
            tmp.unlink(missing_ok=True)
            tmp = out
        else:
            out.unlink(missing_ok=True)
    os.replace(tmp, path)
    return info


def mux_audio(video: Path, audio: dict, out: Path) -> dict:
    """Writes ``out``: the mp4 ``video`` with the first audio stream of ``audio["path"]`` carried
    over unchanged (stream copy), cut at ``audio["duration"]`` seconds when that is given (packet
    by packet: within one audio frame). A stream an mp4 cannot hold as it is (PCM with an older
    ffmpeg, ...) is encoded as AAC instead. Returns ``{"kept", "codec", "copied", "why"}``; when
    the sound cannot be kept (its file is gone, ffmpeg fails) ``kept`` is False and ``why`` says
    why, and ``out`` is not written."""
    src = Path(audio["path"])
    if not src.is_file():
        return {"kept": False, "codec": audio.get("codec"), "copied": False,
                "why": f"the input {src} is no longer there"}
    cut = ["-t", f"{float(audio['duration']):.6f}"] if audio.get("duration") else []
    base = [ffmpeg_exe(), "-nostdin", "-hide_banner", "-loglevel", "error", "-y", "-i", str(video),
            *cut, "-i", str(src), "-map", "0:v:0", "-map", "1:a:0", "-c:v", "copy"]
    why = ""
    for copied, codec in ((True, ["-c:a", "copy"]), (False, ["-c:a", "aac", "-b:a", "256k"])):
        res = subprocess.run([*base, *codec, "-movflags", "+faststart", str(out)],
                             stdin=subprocess.DEVNULL, capture_output=True, text=True)
        if res.returncode == 0 and out.is_file() and mp4_complete(out):
            return {"kept": True, "codec": audio.get("codec"), "copied": copied,
                    "why": "" if copied
                    else f"{audio.get('codec')} cannot be copied into mp4 ({why}): encoded as AAC"}
        why = last_line(res.stderr)
        out.unlink(missing_ok=True)
        if "No space left" in res.stderr:
            raise LayercamError(f"cannot write {out.with_name(video.name)} (the disk is full): {why}")
    return {"kept": False, "codec": audio.get("codec"), "copied": False,
            "why": f"ffmpeg could not carry it over ({why})"}


def mp4_complete(path: str | os.PathLike) -> bool:
    """True when the file at ``path`` is whole as an mp4 container: its top-level boxes tile it
    exactly, and it holds the index (``moov``) and the media (``mdat``). imageio-ffmpeg does not
    report an ffmpeg that failed (a full disk: "Error writing trailer"), and leaves a truncated
    file; this reads only the boxes' 8- or 16-byte headers."""
    import struct

    size, pos, kinds = os.path.getsize(path), 0, set()
    with open(path, "rb") as f:
        while pos < size:
            f.seek(pos)
            head = f.read(8)
            if len(head) < 8:
                return False
            n, kind = struct.unpack(">I4s", head)
            if n == 1:  # a 64-bit size follows
                big = f.read(8)
                if len(big) < 8:
                    return False
                n = struct.unpack(">Q", big)[0]
            elif n == 0:  # to the end of the file
                n = size - pos
            if n < 8 or pos + n > size:
                return False
            kinds.add(kind)
            pos += n
    return {b"moov", b"mdat"} <= kinds


def write_video(path: str | os.PathLike, frames, fps: float = 24.0, crf: int = 18, audio: dict | None = None) -> Path:
    """Encode ``frames`` to an H.264 (libx264, yuv420p) mp4 at ``path``, atomically.

    ``frames``: ``(T,H,W,3)`` RGB, float in [0,1] (clipped) or uint8, ``(T,H,W)`` grey (replicated),
    or any iterable of such frames (encoded as they come: one frame in memory at a time). Odd
    widths/heights are padded to even by repeating the last row/column. ``crf`` is the x264 quality
    (lower is better, 18 is visually lossless); ``audio``: sound to carry over (:class:`VideoWriter`).
    """
    if isinstance(frames, np.ndarray) and frames.ndim not in (3, 4):
        raise ValueError(f"write_video expects (T,H,W,3) frames, got shape {frames.shape}")
    with VideoWriter(path, fps, crf, audio) as vw:
        for f in frames:
            vw.add(f)
    return Path(path)
