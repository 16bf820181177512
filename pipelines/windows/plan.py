"""Where a long clip is cut: the plan (how many windows, how long, how much overlap, and why), the
window bounds, a window's slice of the clip, its exposures and its flow (views of the files on
disk, nothing read), and how two windows share an overlap's frames (:meth:`Plan.weights`, from each
window's fit to them per pixel as its export measured it, :func:`overlap_fits`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from layercam.core.errors import LayercamError


# The shortest window the automatic plan cuts (a camera too fast for the atlas, or the clip's last
# frames): its overlap of a third is then 8 frames, a join that moves each frame 1/9 of the way from
# one window's estimate to the other's.
MIN_WINDOW = 24
FIT_FILE = "fit_map.npy"  # (T, h, w) in a window's export: its squared error per pixel of its model through its camera
                          # against each frame (the HDR writer's faithful step), area-averaged
                          # (:func:`fit_maps`): the join's weights


@dataclass
class Plan:
    """Frame ranges ``[a, b)`` of the windows (one range: a single model) and why."""

    windows: list[tuple[int, int]]
    reason: str
    forced: bool = False
    atlas_px: list[float] = field(default_factory=list)  # each window's atlas extent (px), when measured
    fits: dict = field(default_factory=dict)  # (window, overlap j) -> (h, w): the window's error
                                              # per pixel over overlap j's frames, when measured
    # a fit at a frame's size, made once (:meth:`_fit_at`)
    _sized: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def count(self) -> int:
        return len(self.windows)

    def overlaps(self) -> list[int]:
        return [self.windows[k][1] - self.windows[k + 1][0] for k in range(self.count - 1)]

    def weights(self, t: int, hw: tuple[int, int] | None = None) -> list[tuple[int, float | np.ndarray]]:
        """``[(window, weight), ...]`` of frame ``t`` (one or two windows; weights sum to 1): in an
        overlap, the linear cross-fade from one window to the next. With the frame's size ``hw``
        and where :attr:`fits` has both windows' errors on the overlap, per pixel ``(H, W)`` arrays:
        each side of the fade divided by its window's error there (the error taken as its
        variance, an inverse-variance merge: where one window fits the overlap's frames worse, as
        one that saw that background only in its last frames, the other takes the pixel; equal
        fits keep the fade). The errors are the windows' over all the overlap's frames, not the
        frame's own: the weights then change with the fade alone, not from frame to frame."""
        out = self._fades(t)
        if hw is None or len(out) != 2:
            return out
        (k0, f0), (k1, f1) = out
        if (k0, k0) not in self.fits or (k1, k0) not in self.fits:
            return out
        q0, q1 = f0 / self._fit_at(k0, k0, hw), f1 / self._fit_at(k1, k0, hw)
        w1 = (q1 / (q0 + q1)).astype(np.float32)
        return [(k0, 1.0 - w1), (k1, w1)]

    def _fit_at(self, k: int, j: int, hw: tuple[int, int]) -> np.ndarray:
        """Window ``k``'s fit to overlap ``j`` at the frame's size ``hw`` (bilinear), floored above 0;
        made once per size (the join reads each overlap frame in several passes)."""
        src, key = self.fits[k, j], (k, j, *hw)
        if key not in self._sized or self._sized[key][0] is not src:  # fits given anew are sized anew
            import cv2

            self._sized[key] = (src, np.maximum(cv2.resize(src, (hw[1], hw[0]), interpolation=cv2.INTER_LINEAR), 1e-12))
        return self._sized[key][1]

    def _fades(self, t: int) -> list[tuple[int, float]]:
        out = []
        for k, (a, b) in enumerate(self.windows):
            if not a <= t < b:
                continue
            w = 1.0
            if k + 1 < self.count and t >= self.windows[k + 1][0]:  # fading out into the next
                a2 = self.windows[k + 1][0]
                w = 1.0 - (t - a2 + 1) / (b - a2 + 1)
            if k > 0 and t < self.windows[k - 1][1]:  # fading in from the previous
                b0 = self.windows[k - 1][1]
                w = (t - a + 1) / (b0 - a + 1)
            out.append((k, w))
        return out

    def holding(self, t: int) -> int:
        """The window that holds frame ``t`` most (the later one at an even split)."""
        return max(self.weights(t), key=lambda kw: (kw[1], kw[0]))[0]

    def to_dict(self) -> dict:
        return {"windows": [list(w) for w in self.windows], "overlaps": self.overlaps(),
                "reason": self.reason, "forced": self.forced}


def overlap_for(length: int, cycle: int) -> int:
    """The frames two neighbouring windows ``length`` frames long share and cross-fade over, on a clip
    whose exposures repeat every ``cycle`` frames: a third of the window, rounded down to whole cycles
    where it can (so that both windows see each exposure of the overlap). A share of the window, not
    a count: a window's model knows only its frames, so frames near its end (whose background the
    frames after the window may show better) fit worse than in a window that also holds those, and the
    fade must reach into frames both windows fit well (docs/measurements.md, 2026-11-28)."""
    v = length // 3
    if v >= cycle:
        v -= v % cycle
    return max(v, 1)


def exposure_cycle(exposures) -> int:
    return int(len(np.unique(exposures.phase))) if exposures.phase is not None else 1


def split(T: int, length: int, cycle: int = 1) -> list[tuple[int, int]]:
    """``T`` frames as the fewest windows of at most ``length`` frames overlapping by
    :func:`overlap_for`, their lengths within one frame of each other.

    >>> split(96, 48)
    [(0, 52), (44, 96)]
    >>> split(14, 6, 2)
    [(0, 6), (4, 10), (8, 14)]
    >>> split(40, 48)
    [(0, 40)]
    """
    if length >= T:
        return [(0, T)]
    v = overlap_for(length, cycle)
    n = math.ceil((T - v) / (length - v))
    total = T + (n - 1) * v
    lengths = [total // n + (1 if k < total % n else 0) for k in range(n)]
    out, a = [], 0
    for k, n_k in enumerate(lengths):
        out.append((a, a + n_k))
        a += n_k - v
    return out


def atlas_px(homs: np.ndarray, a: int, b: int, hw: tuple[int, int]) -> float:
    """How many frame pixels a model of frames ``a .. b - 1`` needs across its atlas for one cell
    per pixel (what :func:`layercam.scene.layered.derived_sizes` sizes the atlas grid by): the frames mapped as the
    bootstrap maps them (the pair homographies ``homs`` in frame pixels, ``t -> t + 1``, chained to
    the middle frame; the identity where they move no corner by ``STATIC_CORNER_PX``), fitted into
    the atlas (:func:`layercam.core.geometry.atlas_mappings`), measured by
    :func:`layercam.core.geometry.atlas_pixels`; inf where the chain degenerates."""
    from layercam.core.geometry import (STATIC_CORNER_PX, atlas_mappings, atlas_pixels,
                                        chain_homographies, atlas_box, max_corner_shift,
                                        middle_frame)

    h, w = hw
    with np.errstate(all="ignore"):
        try:
            maps = chain_homographies(np.asarray(homs[a:b - 1], np.float64), middle_frame(b - a))
        except np.linalg.LinAlgError:
            return float("inf")
        if not np.isfinite(maps).all():
            return float("inf")
        c = atlas_box(h, w)
        if ((maps @ c)[:, 2] <= 1e-9).any():  # a corner behind the reference view: no plane holds the frames
            return float("inf")
        if max_corner_shift(maps, h, w) < STATIC_CORNER_PX:
            maps = np.stack([np.eye(3)] * (b - a))
        px = atlas_pixels(atlas_mappings(h, w, maps)[None], hw)
    return px if np.isfinite(px) else float("inf")


def frame_homographies(clip, flow) -> np.ndarray | None:
    """The flow's pair homographies ``t -> t + 1`` ``(T - 1, 3, 3)`` in frame pixels; None where the
    flow measured none."""
    from layercam.vision.scale import rescale_homographies

    if flow is None or flow.homs is None or len(flow.homs) != clip.T - 1:
        return None
    hw = (clip.H, clip.W)
    work = flow.grid if flow.fw is not None else hw
    return rescale_homographies(flow.homs, work, hw) if work != hw else np.asarray(flow.homs, np.float64)


def extent(clip, flow, windows: list[tuple[int, int]]) -> float | None:
    """How many frame pixels the widest of ``windows`` spans across its atlas (:func:`atlas_px`: what
    sizes its model's atlas grid); None where the flow measured no homographies or the chain
    degenerates (then the estimate takes the widest an atlas can be)."""
    homs = frame_homographies(clip, flow)
    if homs is None or clip.T < 2:
        return None
    px = max(atlas_px(homs, a, b, (clip.H, clip.W)) for a, b in windows)
    return px if np.isfinite(px) else None


def plan(clip, exposures, flow, task: str, window=None) -> Plan:
    """The windows of a clip: ``window`` None (auto), 0 (off) or a length in frames.

    Auto: a model holds the clip as long as its atlas does. The atlas grid's finest level has at
    most ``GRID_RES_RANGE[1]`` cells across (:func:`layercam.scene.layered.derived_sizes` sizes it at one cell per frame
    pixel over the frames' extent in the atlas, :func:`atlas_px`: the camera's motion). A clip
    that needs more (a long pan) is cut into the longest windows that need no more, overlapping by
    :func:`overlap_for` (a frame larger than the grid alone: as much as one frame needs; a window
    never shorter than MIN_WINDOW). A static camera's clip fits at any length.
    """
    from layercam.scene.layered import GRID_RES_RANGE

    GRID_MAX_RES = GRID_RES_RANGE[1]

    T = clip.T
    cycle = exposure_cycle(exposures)
    if window is not None and int(window) == 0:
        return Plan([(0, T)], "off (--window 0)", forced=True)
    if task == "fuse-stack" or T < 2:
        return Plan([(0, T)],
                    "one model (a photo stack is one view)" if task == "fuse-stack"
                    else "one model (one frame)")
    if window is not None:
        n = int(window)
        if n < 3:
            raise LayercamError(f"--window {n}: a window needs at least 3 frames (two windows share some of theirs)")
        if n >= T:
            return Plan([(0, T)], f"one model (--window {n} covers the clip's {T} frames)", forced=True)
        w = split(T, n, cycle)
        return Plan(w,
                    f"forced (--window {n}): {len(w)} windows of {w[0][1] - w[0][0]} frames or "
                    f"fewer, overlapping by {overlap_for(n, cycle)}", forced=True)
    homs = frame_homographies(clip, flow)
    if homs is None:
        return Plan([(0, T)], "one model (no flow measured)")
    hw = (clip.H, clip.W)
    cap = max(float(GRID_MAX_RES), max(hw) / 0.9)  # geometry.atlas_mappings: a frame fills 0.9 of the atlas
    whole = atlas_px(homs, 0, T, hw)
    if whole <= cap or T < 2 * MIN_WINDOW:
        if whole <= cap:
            why = f"needs {whole:.0f} px across the atlas at one cell per pixel, within the {cap:.0f} it holds"
        else:
            why = (f"needs {whole:.0f} px across the atlas, more than the {cap:.0f} it holds, but is shorter than two "
                   f"windows of {MIN_WINDOW} frames")
        return (Plan([(0, T)],
                     f"one model: the camera's motion over the {T} frames {why} (--window N cuts "
                     "it)", atlas_px=[whole]))
    out, sizes, a = [], [], 0
    while True:
        b = a + 2
        while b < T and atlas_px(homs, a, b + 1, hw) <= cap:
            b += 1
        b = min(max(b, a + MIN_WINDOW), T)  # a camera too fast for the atlas: windows of the shortest length
        if T - b < MIN_WINDOW // 2 and b < T:  # what is left would be a sliver: this window takes it
            b = T
        out.append((a, b))
        sizes.append(atlas_px(homs, a, b, hw))
        if b >= T:
            break
        a = b - overlap_for(b - a, cycle)
    if len(out) == 1:
        return Plan(out,
                    f"one model: the camera's motion over the {T} frames needs {whole:.0f} px "
                    f"across the atlas, more than the {cap:.0f} it holds, but less than two "
                    "windows' worth (--window N cuts it)", atlas_px=sizes)
    longest = max(b - a for a, b in out)
    return Plan(out,
                f"{len(out)} windows of up to {longest} frames: the camera's motion over the {T} "
                f"frames needs {whole:.0f} px across the atlas at one cell per pixel, "
                f"more than the {cap:.0f} it holds ({GRID_MAX_RES} cells); each window's frames "
                "fit it (--window N or off overrides)", atlas_px=sizes)


# -- one window --------------------------------------------------------------------------------------
def sub_clip(clip, a: int, b: int):
    from layercam.io.clip import Clip

    meta = {k: (list(v)[a:b] if isinstance(v, (list, tuple)) and len(v) == clip.T else v) for k,
            v in clip.meta.items()}  # per frame: its slice
    meta["notes"] = []  # said once, by the whole clip's run
    meta["window"] = [a, b]
    exif = None if clip.exif_exposures is None else list(clip.exif_exposures)[a:b]
    # frames on disk: a view, nothing read
    frames = clip.frames.rows(a, b) if hasattr(clip.frames, "rows") else clip.frames[a:b]
    return Clip(frames, clip.source, list(clip.names)[a:b], clip.fps, clip.bit_depth, exif, meta)


def sub_exposures(e, a: int, b: int):
    from layercam.io import Exposures

    return Exposures(e.log2_dt[a:b], e.learn, None if e.phase is None else e.phase[a:b], e.spec,
                     e.reason, None if e.dt_seconds is None else e.dt_seconds[a:b])


def sub_flow(flow, a: int, b: int):
    """The whole clip's flow (:class:`~layercam.vision.flow_store.FlowArrays`) for the pairs inside
    frames ``a .. b - 1``: views, nothing read."""
    return None if flow is None else flow.rows(a, b - 1)


def rows(x, a: int, b: int):
    """Rows ``a:b`` of an array: a view (of a :class:`~layercam.io.frames.DiskArray`: nothing read)."""
    return x.rows(a, b) if hasattr(x, "rows") else np.asarray(x)[a:b]



def overlap_fits(p: Plan, dirs: list[Path]) -> dict:
    """``{(window, overlap j): (h, w)}``: each window's squared error per pixel over the frames of
    the overlaps it shares (overlap ``j``: windows ``j`` and ``j + 1``), the mean over those frames
    of how well its model reproduced each through its camera as its export measured it
    (:data:`FIT_FILE`, written by the HDR writer's faithful step for a window), smoothed by the
    faithful step's window (``faithful.WINDOW_SIGMA``); {} where an export has none (no faithful
    step, or a deblurred clip): :meth:`Plan.weights` then keeps the plain fade."""
    import cv2

    from layercam.camera.faithful import WINDOW_SIGMA

    if not all((Path(d) / FIT_FILE).is_file() for d in dirs):
        return {}
    fits: dict = {}
    for j in range(p.count - 1):
        a, b = p.windows[j + 1][0], p.windows[j][1]
        for k in (j, j + 1):
            maps = np.load(Path(dirs[k]) / FIT_FILE, mmap_mode="r")
            mean = np.asarray(maps[a - p.windows[k][0]:b - p.windows[k][0]], np.float32).mean(0)
            fits[k, j] = cv2.GaussianBlur(mean, (0, 0), WINDOW_SIGMA)
    return fits


def fit_maps(cache: Path, T: int, hw: tuple[int, int]) -> np.ndarray:
    """``cache / FIT_FILE``: ``(T, h, w)`` float32 on disk, ``hw = (h, w)`` the maps' size."""
    return np.lib.format.open_memmap(Path(cache) / FIT_FILE, mode="w+", dtype=np.float32, shape=(T, *hw))


def area(x: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    """``x (H, W)`` area-averaged to ``hw``."""
    import cv2

    return x if x.shape == tuple(hw) else cv2.resize(np.asarray(x, np.float32), (hw[1], hw[0]),
                                                     interpolation=cv2.INTER_AREA)


def per_pixel(w, x: np.ndarray):
    """A join's weight ``w`` (a number, or ``(H, W)`` per pixel) shaped to multiply ``x`` (``(H,
    W)`` or ``(H, W, C)``)."""
    return w[..., None] if np.ndim(w) == 2 and x.ndim == 3 else w
