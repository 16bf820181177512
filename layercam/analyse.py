"""Decide what the model for one clip contains: measure the clip, then choose. Every decision
carries its measured reason and is written into the config's ``model`` section (and the blur
generator's shape); a value set there (a flag such as ``--layers 2``, or ``--set``) is kept.

Measures (:func:`measure`): exposure variation (from the spec, or brightness of registered
neighbours), clipped fractions, global motion (homography fit of the cached flow), independent
motion (flow residual after the homography, in consistent pixels), per-frame sharpness (Laplacian
energy of contrast-normalised grey frames) and the blur it implies relative to the sharpest frame.
"""

from __future__ import annotations

import math

import numpy as np

from layercam.colour import REC601, luma
from layercam.config import AUTO, Config

# thresholds of the rules (each documented where it is used)
IND_MOTION_PX = 1.5          # residual flow (px) beyond which a pixel moves on its own
IND_MOTION_FRAC = (0.02, 0.6)  # fraction of such pixels that makes a foreground (not noise, not all):
                             # camera shake puts flow errors on up to 1.4% of the pixels of a pair
                             # (synth shake, 96x96); an object moving on its own covered 9-15%
IND_MOTION_PAIRS = 0.3       # ... in at least this fraction of neighbour pairs
STATIC_PX = 0.3              # below this mean flow the scene is static: no flow loss needed
BLUR_SIGMA = 0.8             # estimated relative blur (Gaussian sigma, px) that needs a blur generator
BLUR_5X5_SIGMA = 2.5         # beyond this a 3x3 patch cannot reach: 5x5
OFFSET_PER_SIGMA = 5.0       # max offset (px) per px of relative blur: the energy match underestimates
                             # motion and disc blur (8 px shake reads as sigma ~0.9; s = 5 in the paper)
SIGMAS = (0.0, 0.5, 0.8, 1.2, 1.6, 2.0, 2.5, 3.0, 4.0, 5.0)


def _grey(frame: np.ndarray) -> np.ndarray:
    return luma(frame, REC601).astype(np.float32)


def laplacian_energy(frame: np.ndarray) -> float:
    """Variance of the Laplacian of the grey frame, normalised by its contrast (so that exposure
    changes do not read as sharpness changes); clipped pixels are left out."""
    import cv2

    g = _grey(frame)
    ok = (g > 0.02) & (g < 0.98)
    if ok.sum() < 16:
        return 0.0
    g = (g - g[ok].mean()) / max(float(g[ok].std()), 1e-4)
    lap = cv2.Laplacian(g, cv2.CV_32F, ksize=3)
    ok = cv2.erode(ok.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    return float(lap[ok].var()) if ok.any() else 0.0


def relative_blur(frames: np.ndarray, energies: np.ndarray) -> np.ndarray:
    """Per frame, the Gaussian sigma (px) that brings the sharpest frame to its Laplacian energy."""
    import cv2

    ref = frames[int(np.argmax(energies))]
    table = []
    for s in SIGMAS:
        table.append(laplacian_energy(cv2.GaussianBlur(ref, (0, 0), s) if s > 0 else ref))
    table = np.array(table)
    out = []
    for e in energies:
        # energies fall with sigma: the first sigma whose energy drops below the frame's
        idx = np.searchsorted(-table, -e)
        if idx <= 0:
            out.append(0.0)
        elif idx >= len(SIGMAS):
            out.append(SIGMAS[-1])
        else:  # interpolate in log energy
            e0, e1 = math.log(max(table[idx - 1], 1e-9)), math.log(max(table[idx], 1e-9))
            f = (math.log(max(e, 1e-9)) - e0) / (e1 - e0) if e1 != e0 else 0.0
            out.append(SIGMAS[idx - 1] + f * (SIGMAS[idx] - SIGMAS[idx - 1]))
    return np.array(out, dtype=np.float32)


def measure(clip, exposures, flow: dict | None) -> dict:
    """The numbers the decisions are made from. ``flow`` is the flow stage's arrays or None."""
    frames = clip.frames
    g = frames.max(-1)
    m: dict = {
        "frames": clip.T,
        "distinct_exposures": exposures.count_distinct,
        "exposure_range_ev": float(np.ptp(exposures.log2_dt)) if exposures.T else 0.0,
        "clipped_high": float((g >= 0.99).mean()),
        "clipped_low": float((frames.max(-1) <= 0.01).mean()),
    }
    energies = np.array([laplacian_energy(f) for f in frames])
    m["sharpness"] = energies.round(4).tolist()
    m["sharpness_spread"] = float(energies.max() / max(energies.min(), 1e-9)) if len(energies) else 1.0
    blur = relative_blur(frames, energies) if clip.T > 1 else np.zeros(1, np.float32)
    m["relative_blur_sigma"] = blur.round(2).tolist()
    m["max_blur_sigma"] = float(blur.max())
    if flow is None or "fw" not in flow or len(flow["fw"]) == 0:
        m.update(global_motion_px=0.0, independent_motion_frac=0.0, independent_pairs=0.0, flow_consistent=1.0)
        return m
    from layercam.flow import residual_motion

    fw = flow["fw"].astype(np.float32)
    ok = flow["fw_ok"]
    homs = flow["homs"]
    mag = np.sqrt((fw**2).sum(-1))
    m["global_motion_px"] = float(np.median(mag))
    m["flow_consistent"] = float(ok.mean())
    res = residual_motion(fw, homs)
    thr = IND_MOTION_PX + 0.05 * mag.mean(axis=(1, 2), keepdims=True)
    moving = (res > thr) & ok
    frac = moving.mean(axis=(1, 2))
    lo, hi = IND_MOTION_FRAC
    m["independent_motion_frac"] = float(np.median(frac))
    m["independent_pairs"] = float(((frac > lo) & (frac < hi)).mean())
    return m


TASK_BLUR = ("deblur-video", "fuse-stack")  # tasks that ask for the blur to be explained
MODEL_KEYS = ("layers", "tone_mapper", "exposures", "blur", "max_offset", "flow_loss")  # what the analysis reports


def decide(cfg: Config, clip, exposures, task: str, measures: dict | None = None) -> tuple[Config, dict]:
    """The analysis's choices written into a copy of ``cfg``: each ``auto`` of the ``model`` section
    (layers, tone mapper, exposures, blur generator, flow loss) and of the blur generator's ``n``
    and ``max_offset``; returns ``(cfg, reasons)``, one measured reason per choice. A value that is
    not ``auto`` (a flag such as ``--layers 2``, or ``--set``) is kept and its reason says so.
    Without ``measures`` (no flow yet) only the exposure-based choices are informed.
    """
    cfg = cfg.copy()
    m, b = cfg.model, cfg.blur
    mm = measures or {}
    r: dict = {}

    def forced(key: str, value) -> bool:
        if value == AUTO:
            return False
        r[key.split(".")[1]] = f"forced ({key}={value})"
        return True

    # layers: a second layer only when something moves against the camera's global motion
    pairs = mm.get("independent_pairs", 0.0)
    frac = mm.get("independent_motion_frac", 0.0)
    if not forced("model.layers", m.layers):
        if clip.T > 1 and pairs >= IND_MOTION_PAIRS:
            m.layers = 2
            r["layers"] = f"independent motion in {pairs:.0%} of frame pairs (median {frac:.1%} of pixels beyond {IND_MOTION_PX} px of the global homography)"
        else:
            m.layers = 1
            r["layers"] = f"no independent motion (in {pairs:.0%} of pairs)" if measures else "one layer (no flow measured)"

    # tone mapper: a response curve is only identifiable from more than one exposure
    n_exp = exposures.count_distinct
    learned = exposures.learn != "none"
    if not forced("model.tone_mapper", m.tone_mapper):
        if n_exp > 1 or learned:
            m.tone_mapper = "learned"
            r["tone_mapper"] = f"{n_exp} distinct exposures" + (" (learned)" if learned else "")
        else:
            m.tone_mapper = "fixed"
            r["tone_mapper"] = "one exposure: no response curve can be learned, sRGB assumed"
    if m.exposures == "learned" and not learned:
        m.exposures, r["exposures"] = "given", "exposures were given; nothing to learn"
    elif not forced("model.exposures", m.exposures):
        m.exposures, r["exposures"] = ("learned" if learned else "given"), exposures.reason

    # blur: frames that are blurrier than the sharpest one by more than BLUR_SIGMA
    sigma = mm.get("max_blur_sigma", 0.0)
    measured = bool(measures) and sigma >= BLUR_SIGMA
    if not forced("model.blur", m.blur):
        if measured:
            m.blur, r["blur"] = "on", f"frames up to {sigma:.1f} px (Gaussian sigma) blurrier than the sharpest"
        elif task in TASK_BLUR:  # the task asks for the blur to be explained; the global measure misses
            # uniform blur and focus that differs by region (8 px shake reads as 0.7, a Lytro pair as 0.7)
            m.blur = "on"
            r["blur"] = f"task {task}" + (f" (measured relative blur {sigma:.1f} px)" if measures else " (no measurement)")
        else:
            m.blur = "off"
            r["blur"] = f"sharp input: relative blur {sigma:.1f} px < {BLUR_SIGMA}" if measures else "no blur expected"
    if not forced("blur.n", b.n):
        b.n = 5 if measured and sigma >= BLUR_5X5_SIGMA else 3
    if not forced("blur.max_offset", b.max_offset):
        if m.blur == "off":
            b.max_offset, r["max_offset"] = 5.0, "unused (blur off)"
        elif measured:
            b.max_offset = float(min(max(math.ceil(OFFSET_PER_SIGMA * sigma), 2.0), 8.0))
            r["max_offset"] = f"{OFFSET_PER_SIGMA:g} x the largest relative blur, {b.max_offset:.0f} px"
        else:
            b.max_offset, r["max_offset"] = 5.0, "default (nothing measured)"

    # flow loss: only helps when things move
    motion = mm.get("global_motion_px", 0.0)
    if not forced("model.flow_loss", m.flow_loss):
        if clip.T < 2:
            m.flow_loss, r["flow_loss"] = False, "a single frame has no neighbours"
        elif measures and motion < STATIC_PX and m.layers == 1:
            m.flow_loss, r["flow_loss"] = False, f"static scene (median flow {motion:.2f} px)"
        else:
            m.flow_loss = True
            r["flow_loss"] = f"median flow {motion:.2f} px" if measures else "more than one frame"
    return cfg, r


def model_summary(cfg: Config) -> dict:
    """The decided model as the report and the analysis table show it: ``{"layers": 1, "blur":
    "3x3" | "off", "max_offset": 5.0, ...}``."""
    m, b = cfg.model, cfg.blur
    return {"layers": m.layers, "tone_mapper": m.tone_mapper, "exposures": m.exposures, "blur": "off" if m.blur == "off" else f"{b.n}x{b.n}", "max_offset": b.max_offset, "flow_loss": m.flow_loss}


def format_table(cfg: Config, reasons: dict) -> str:
    s = model_summary(cfg)
    rows = [(k, str(s[k]), reasons.get(k, "")) for k in MODEL_KEYS]
    w0 = max(len(a) for a, _, _ in rows)
    w1 = max(len(b) for _, b, _ in rows)
    return "\n".join(f"  {a:<{w0}}  {b:<{w1}}  {c}" for a, b, c in rows)


def resolve_auto(cfg: Config, static: bool, h0, frame_hw: tuple[int, int]) -> Config:
    """The settings left ``auto`` until the bootstrap has run, resolved in a copy of ``cfg``:

    * a static one-layer scene (``static``: the bootstrap found the frames registered by the
      identity) has no residual warp (``scene.residual`` -> ``off``, ``scene.residual_scale = 0``)
      and PSFs centred on their pixel (``blur.centre`` -> ``on``); elsewhere the residual is on
      and the centre free. A static stack has nothing for a free per-pixel warp or a PSF shift to
      follow, and both were used to fit the images' blur instead (README, How it works). On moving
      footage the shift stays free: centred, the PSFs of the Adobe240 triplet grew to 4 px on its
      sharp background, which came out over-sharpened.
    * ``scene.grid_max_res = 0``: the finest atlas grid level from the atlas's extent in frame
      pixels (:func:`layercam.geometry.atlas_pixels` of the bootstrap mappings ``h0 (L, T, 3, 3)``),
      within 32..2048: without a blur generator the power of two at or above it (at least one cell
      per pixel); with one, the extent itself (at most one cell per pixel). The blur generator
      samples the scene between pixels, so a finer grid lets the scene keep sub-pixel content that
      each image's PSF reads on its own, fitting every image without one sharp scene (the PSFs
      collapsed to deltas on the focus x exposure stack: ``docs/measurements.md``).
    """
    from layercam.geometry import atlas_pixels

    cfg = cfg.copy()
    static = cfg.model.layers == 1 and bool(static)
    if cfg.scene.residual == AUTO:
        cfg.scene.residual = "off" if static else "on"
    if cfg.scene.residual == "off" and cfg.scene.deformation == "homography":
        cfg.scene.residual_scale = 0.0
    if cfg.blur.centre == AUTO:
        cfg.blur.centre = "on" if static else "off"
    s = cfg.scene
    if s.encoding == "grid" and s.grid_max_res == 0:
        px = atlas_pixels(h0, frame_hw)
        res = int(round(px)) if cfg.model.blur == "on" else 2 ** math.ceil(math.log2(max(px, 2.0)))
        s.grid_max_res = int(min(max(res, 32), 2048))
        s.grid_min_res = min(s.grid_min_res, s.grid_max_res)
    return cfg
