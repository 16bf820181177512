"""A long clip, or one larger than the flow's working grid, segmented in overlapping windows of
frames on that grid, so that the finder's memory is that of a ``SEG_FRAMES``-frame clip whatever
the clip's length; the masks go to disk (``masks.raw``)."""

from __future__ import annotations

import numpy as np

from layercam.core.config import SegmentConfig
from layercam.core.heap import give_back_freed_memory
from layercam.vision.segment.mapping import foreground_mappings
from layercam.vision.segment.store import mask_coverage


SEG_FRAMES = 48   # a clip longer than this is segmented in windows of this many frames (foreground_bootstrap_long):
SEG_MARGIN = 8    # memory and the colour model of a 48-frame clip, whatever its length; windows overlap by this
                  # many frames on each side (the default segment.reach: what a frame's motion evidence sees)


def segment_windows(T: int) -> list[tuple[int, int, int, int]]:
    """``(a0, b0, a, b)`` per window: frames ``a0:b0`` are segmented together, and ``a:b`` (its
    middle, ``SEG_FRAMES - 2 SEG_MARGIN`` frames) keep their masks; the cores tile ``0:T``.

    >>> segment_windows(40)
    [(0, 40, 0, 40)]
    >>> segment_windows(100)[:2], segment_windows(100)[-1]
    ([(0, 40, 0, 32), (24, 72, 32, 64)], (88, 100, 96, 100))
    """
    if T <= SEG_FRAMES:
        return [(0, T, 0, T)]
    core = SEG_FRAMES - 2 * SEG_MARGIN
    return [(max(a - SEG_MARGIN, 0), min(a + core + SEG_MARGIN, T), a, min(a + core, T)) for a in range(0, T, core)]


def windowed(T: int, hw: tuple[int, int], work: tuple[int, int]) -> bool:
    """Whether a two-layer clip of ``T`` frames of ``hw`` with flow on the grid ``work`` is
    segmented by :func:`foreground_bootstrap_long` (more than ``SEG_FRAMES`` frames, or frames
    larger than the flow's working grid) rather than whole, at the frames' size."""
    return T > SEG_FRAMES or tuple(work) != tuple(hw)


def window_at_work(frames, flows: dict, a0: int, b0: int, grid: tuple[int, int]) -> tuple[np.ndarray, dict]:
    """Frames ``a0:b0`` and their pairs' ``fw``, ``bw``, ``fw_ok``, ``bw_ok`` at the finder's working
    size (``segment.WORK_SHORT`` on the short side of ``grid``, the flow's grid), read a frame or a
    pair at a time: the same arrays as ``segment._working`` of the window read whole at ``grid`` (the
    frames scaled to ``grid`` first, as the flow saw them), without the window at ``grid`` in memory.
    Frames ``(b0-a0, h, w, 3)`` float32; flows ``(b0-a0-1, h, w, 2)`` float32, checks bool."""
    from layercam.vision.scale import resize_frames, working_size
    from layercam.vision.segment import WORK_SHORT, check_at, flow_at

    work = working_size(tuple(grid), WORK_SHORT)
    fr = np.empty((b0 - a0, *work, 3), np.float32)
    for t in range(a0, b0):  # as the flow saw the frame (at its grid), then at the working size
        fr[t - a0] = resize_frames(resize_frames(np.asarray(frames[t], np.float32)[None], tuple(grid)), work)[0]
    fl = {k: np.stack([flow_at(flows[k][i], work) for i in range(a0, b0 - 1)]) for k in ("fw", "bw")}
    for k in ("fw_ok", "bw_ok"):
        if flows.get(k) is not None:
            fl[k] = np.stack([check_at(flows[k][i], work) for i in range(a0, b0 - 1)])
    return fr, fl


def foreground_bootstrap_long(frames, flows: dict, out, masks, cfg: SegmentConfig, progress: bool = False) -> dict:
    """:func:`foreground_bootstrap` for a long clip or one larger than the flow's working grid
    (:func:`windowed`), with the memory of a ``SEG_FRAMES``-frame clip at the finder's working size:
    each window of :func:`segment_windows` is read at that size (:func:`window_at_work`) and
    segmented by :func:`find_foreground`, each frame's mask taken from the window it is the middle
    of, scaled up to the flow's grid and then to the frames' size (bilinear, at 0.5, as
    :func:`foreground_bootstrap` would) and written to ``out/masks.raw`` (uint8, :func:`load_masks`
    reads it); then the foreground mapping from all of them and the flows, read a frame or a pair at
    a time. ``flows`` as the flow stage keeps them (possibly at a working size and on disk);
    ``masks`` given by the user are not segmented again. Returns what :func:`foreground_bootstrap`
    does, ``masks`` the ``DiskArray``."""
    import json
    from pathlib import Path

    import cv2

    from layercam.vision.scale import AtFrameSize
    from layercam.core.interrupts import reached
    from layercam.io.frames import DiskArray
    from layercam.vision.segment import find_foreground
    from layercam.core.progress import bar

    T, H, W = frames.shape[:3]
    h, w = flows["fw"].shape[1:3]
    info: dict = {}
    computed = masks is None
    if computed:
        out = Path(out)
        masks = DiskArray.create(out / "masks.raw", np.uint8, (T, H, W))
        (out / "masks.json").write_text(json.dumps({"shape": [T, H, W]}))
        wins = segment_windows(T)
        models = []
        up = lambda m, size: m if m.shape[:2] == size else (cv2.resize(m, (size[1], size[0]),
            interpolation=cv2.INTER_LINEAR) > 0.5).astype(np.float32)  # noqa: E731
        for i, (a0, b0, a,
                b) in enumerate(bar(wins, desc="bootstrap (windows)", unit="window",
                                    enabled=progress and len(wins) > 1)):
            reached("segment", i)
            fr, fl = window_at_work(frames, flows, a0, b0, (h, w))
            part, inf = find_foreground(fr, fl, cfg)
            del fr, fl
            if cfg.detector:  # as foreground_bootstrap, on the flow's grid
                from layercam.vision.scale import resize_frames
                from layercam.vision.segment import detector_masks

                small = resize_frames([frames[t] for t in range(a0, b0)], (h, w))
                part, _ = detector_masks(small, np.stack([up(m, (h, w)) for m in np.asarray(part, np.float32)]), cfg)
                del small
            for t in range(a, b):  # working size -> the flow's grid -> the frames' size, each at 0.5
                masks[t] = up(up(np.asarray(part[t - a0], np.float32), (h, w)), (H, W)) > 0.5
            models.append(inf.get("model"))
            del part, inf
            give_back_freed_memory()
        masks.flush()
        cover = mask_coverage(masks)
        info = {"windows": len(wins), "window_frames": SEG_FRAMES, "window_margin": SEG_MARGIN,
                "grid": [h, w], "models": models,
                "coverage_mean": float(cover.mean()), "coverage_min": float(cover.min()),
                "coverage_max": float(cover.max()), "empty_frames": int((cover == 0).sum())}
    fw, fw_ok = AtFrameSize(flows["fw"], (H, W)), AtFrameSize(flows["fw_ok"], (H, W))
    h0, desc = foreground_mappings(H, W, masks, fw, fw_ok, margin=cfg.margin, how=cfg.foreground)
    return {"h0": h0, "masks": masks, "computed": computed, "how": desc, "info": info}
