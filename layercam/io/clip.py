"""A clip: the frames of one input (video file, folder of images, list of images) as
``(T,H,W,3)`` RGB in [0,1] (:class:`layercam.io.frames.Frames`: stored compactly, in memory or in a
file on disk, read as float32 a frame or a window at a time), with per-frame names, fps, bit depth
and EXIF exposures. ``load_clip`` decodes frame by frame into a file (the run's cache, or an
unlinked temporary file), so that no stage ever holds the whole clip.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np

from layercam.io.frames import Frames

__all__ = ["Clip", "fingerprint"]


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
        input's header says, :func:`layercam.io.ffmpeg.parse_header`) and ``audio`` (the sound the
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
