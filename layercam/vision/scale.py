"""Flow at a working size: frames whose short side is longer than ``WORKING_SHORT_SIDE`` are flowed on
scaled copies; flows, masks and homographies are carried back to the frame's size (``AtFrameSize``,
read a pair at a time;
:func:`layercam.vision.flow_store.at_frame_size`, the flow stage's arrays)."""

from __future__ import annotations

import numpy as np


WORKING_SHORT_SIDE = 540  # flow of frames whose short side is longer is computed on copies scaled to it and read


def working_size(hw: tuple[int, int], short_side: int | None = None) -> tuple[int, int]:
    """The ``(h, w)`` flow is computed at for frames of ``hw = (H, W)``: the frames' own size when
    their short side is at most ``short_side`` (default :data:`WORKING_SHORT_SIDE`; 0: always),
    else scaled down to it."""
    short_side = WORKING_SHORT_SIDE if short_side is None else short_side
    h, w = int(hw[0]), int(hw[1])
    if not short_side or min(h, w) <= short_side:
        return h, w
    s = short_side / min(h, w)
    return max(int(round(h * s)), 1), max(int(round(w * s)), 1)


def size_within(hw: tuple[int, int], pixels: int) -> tuple[int, int]:
    """``hw = (H, W)`` scaled down (aspect kept) to at most about ``pixels`` pixels; unchanged when within.

    >>> size_within((1080, 1920), 65536)
    (192, 341)
    """
    h, w = int(hw[0]), int(hw[1])
    s = min(1.0, (pixels / (h * w)) ** 0.5)
    return max(1, round(h * s)), max(1, round(w * s))


def resize_frames(frames: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``(T, H, W, 3)`` -> ``(T, h, w, 3)`` float32 (area averaging), one frame at a time."""
    import cv2

    h, w = size
    out = np.empty((len(frames), h, w, 3), np.float32)
    for t, f in enumerate(frames):
        out[t] = cv2.resize(np.asarray(f, np.float32), (w, h), interpolation=cv2.INTER_AREA)
    return out


def pixel_scaling(from_hw: tuple[int, int], to_hw: tuple[int, int]) -> np.ndarray:
    """``(3, 3)`` map of pixel coordinates of an image of size ``to_hw`` to those of the same image
    resized to ``from_hw`` (:mod:`layercam.core.geometry`'s pixel coordinates, the frame's edges
    kept: ``x_from = (x_to + 0.5) * s - 0.5``)."""
    sy, sx = from_hw[0] / to_hw[0], from_hw[1] / to_hw[1]
    return np.array([[sx, 0.0, 0.5 * sx - 0.5], [0.0, sy, 0.5 * sy - 0.5], [0.0, 0.0, 1.0]])


def rescale_homographies(homs: np.ndarray, from_hw: tuple[int, int], to_hw: tuple[int, int]) -> np.ndarray:
    """Homographies between pixel coordinates of frames of size ``from_hw`` -> the same motion in
    pixel coordinates of size ``to_hw``: ``A^-1 H A`` with ``A`` = :func:`pixel_scaling`."""
    a = pixel_scaling(from_hw, to_hw)
    out = np.linalg.inv(a)[None] @ np.asarray(homs, np.float64) @ a[None]
    return out / out[:, 2:3, 2:3]


def upsample_flow(fw: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    """Flows ``(N, h, w, 2)`` in pixels of their own grid -> ``(N, H, W, 2)`` float32 in pixels of
    ``hw = (H, W)`` (bilinear); unchanged when the sizes already agree."""
    import cv2

    n, h, w = fw.shape[:3]
    H, W = hw
    if (h, w) == (H, W):
        return np.asarray(fw, np.float32)
    out = np.empty((n, H, W, 2), np.float32)
    scale = np.array([W / w, H / h], np.float32)
    for i in range(n):
        out[i] = cv2.resize(np.asarray(fw[i], np.float32), (W, H), interpolation=cv2.INTER_LINEAR) * scale
    return out


def upsample_mask(ok: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    """Masks ``(N, h, w)`` -> ``(N, H, W)`` bool (nearest)."""
    import cv2

    n, h, w = ok.shape[:3]
    if (h, w) == tuple(hw):
        return np.asarray(ok, bool)
    return np.stack([cv2.resize(m.astype(np.uint8), (hw[1], hw[0]),
                                interpolation=cv2.INTER_NEAREST).astype(bool) for m in ok])


class AtFrameSize:
    """The flow stage's flows ``(N, h, w, 2)`` or masks ``(N, h, w)`` (possibly on disk, at a
    working size) read one pair at a time at the frames' size ``hw``: ``a[i]`` is
    :func:`upsample_flow` (or :func:`upsample_mask`) of pair ``i``; ``shape`` and ``len`` as the
    full-size array's."""

    def __init__(self, a, hw: tuple[int, int]):
        self.a, self.hw = a, (int(hw[0]), int(hw[1]))
        self.flow = len(a.shape) == 4
        self.shape = (len(a), *self.hw, *((2,) if self.flow else ()))

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, i: int) -> np.ndarray:
        one = np.asarray(self.a[i : i + 1]) if isinstance(i, (int, np.integer)) else None
        if one is None:
            raise TypeError("AtFrameSize is read a pair at a time: a[i]")
        return (upsample_flow(one, self.hw) if self.flow else upsample_mask(one, self.hw))[0]


class ResizedFrames:
    """Frames read one at a time at ``hw`` (area averaging, as :func:`resize_frames`)."""

    def __init__(self, frames, hw: tuple[int, int]):
        self.frames, self.hw, self.shape = frames, tuple(hw), (len(frames), *hw, 3)

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, t: int) -> np.ndarray:
        import cv2

        f = np.asarray(self.frames[t], np.float32)
        return f if f.shape[:2] == self.hw else cv2.resize(f, (self.hw[1], self.hw[0]), interpolation=cv2.INTER_AREA)
