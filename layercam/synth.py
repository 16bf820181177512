"""Deterministic synthetic scenes rendered through a known camera, with ground truth.

Every family draws all its randomness from ``numpy.random.default_rng(seed)``, so the same
arguments give bit-identical frames. The imaging model is

    irradiance E (linear, HDR)  ->  E * t * gain  ->  clip [0,1]  ->  CRF  ->  + N(0, noise)
    ->  clip [0,1]  ->  8-bit quantisation

where ``t`` is the exposure time (``SynthScene.exposure_times``, relative seconds) and ``gain``
(``meta["gain"]``) a constant of the scene. The noise is added after the CRF, in the LDR
domain, so that ``noise`` is in units of output intensity. ``SynthScene.hdr`` is ``E`` itself,
i.e. a tool that recovers irradiance is right up to one scale per channel.

Families (``FAMILIES``, dispatch with ``make``):

* ``pan_hdr``: a camera pans and zooms across an HDR canvas, alternating exposures.
* ``static_single``: a static camera, one exposure, sharp frames.
* ``moving_object``: ``pan_hdr`` plus an independently moving textured blob (``fg_mask``).
* ``shake_blur``: camera-shake motion blur (integrated in linear irradiance), ``sharp_ldr``.
* ``mfme_stack``: a static multi-focus multi-exposure stack of depth planes, ``allfocus_hdr``.

Geometry: for families with a camera path, ``meta["frame_affine"]`` is ``(T,2,3)``, mapping a
frame pixel ``(x, y, 1)`` (pixel centres at integers, OpenCV convention) to canvas coordinates;
``true_flow(scene)`` turns it (and the object's ``meta["object_affine"]``) into ground-truth
forward optical flow.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from layercam.colour import REC709, luma, srgb_decode, srgb_encode
from layercam.errors import LayercamError
from layercam.io.clip import Clip

__all__ = [
    "CRFS",
    "FAMILIES",
    "SynthScene",
    "crf_apply",
    "crf_inverse",
    "hdr_canvas",
    "make",
    "mfme_stack",
    "moving_object",
    "pan_hdr",
    "shake_blur",
    "static_single",
    "true_flow",
]


# --------------------------------------------------------------------------------------------
# Result type
# --------------------------------------------------------------------------------------------


@dataclass
class SynthScene:
    """A rendered synthetic scene and its ground truth.

    clip: LDR frames ``(T,H,W,3)`` float32, 8-bit quantised, in [0,1];
        ``clip.source == "synthetic:<family>"``.
    exposure_times: ``(T,)`` float64 relative exposure times (what a user would pass).
    hdr: ``(T,H,W,3)`` float32 linear sharp irradiance per frame (ground truth up to a
        per-channel scale).
    crf: name of the CRF used (see ``CRFS``).
    fg_mask: ``(T,H,W)`` bool foreground ground truth, or None.
    meta: family, parameters, ``gain``, geometry, blur kernels, focus settings...
    sharp_ldr: ``(T,H,W,3)`` noise-free sharp LDR ground truth (deblur families), or None.
    allfocus_hdr: ``(H,W,3)`` all-in-focus HDR (``mfme_stack``), or None.
    """

    clip: Clip
    exposure_times: np.ndarray
    hdr: np.ndarray
    crf: str
    fg_mask: np.ndarray | None = None
    meta: dict = field(default_factory=dict)
    sharp_ldr: np.ndarray | None = None
    allfocus_hdr: np.ndarray | None = None

    @property
    def frames(self) -> np.ndarray:
        """The LDR frames ``(T,H,W,3)`` (same as ``clip.frames``)."""
        return self.clip.frames


# --------------------------------------------------------------------------------------------
# Camera response functions
# --------------------------------------------------------------------------------------------

CRFS = ("gamma", "srgb", "scurve", "mixed")

_SCURVE_EPS = 1.0 / 1024.0
_SCURVE_DEFAULT = (1.2, float(np.log(0.10)))  # (slope a per natural-log unit, midpoint m)
_SCURVE_MIXED = (
    (1.05, float(np.log(0.08))),
    (1.2, float(np.log(0.10))),
    (1.35, float(np.log(0.13))),
)


def _sigmoid(u: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-u))


def _scurve(x: np.ndarray, a: float, m: float) -> np.ndarray:
    """Sigmoid in the log domain, normalised so that 0 -> 0 and 1 -> 1 (monotone, smooth)."""
    lo = _sigmoid(a * (np.log(_SCURVE_EPS) - m))
    hi = _sigmoid(a * (np.log(1.0 + _SCURVE_EPS) - m))
    return (_sigmoid(a * (np.log(x + _SCURVE_EPS) - m)) - lo) / (hi - lo)


def _scurve_inv(y: np.ndarray, a: float, m: float) -> np.ndarray:
    lo = _sigmoid(a * (np.log(_SCURVE_EPS) - m))
    hi = _sigmoid(a * (np.log(1.0 + _SCURVE_EPS) - m))
    s = np.clip(y * (hi - lo) + lo, 1e-12, 1.0 - 1e-12)
    return np.exp(m + np.log(s / (1.0 - s)) / a) - _SCURVE_EPS


def _check_crf(name: str) -> None:
    if name not in CRFS:
        raise LayercamError(f"unknown CRF {name!r}; choose one of {', '.join(CRFS)}")


def crf_apply(x: np.ndarray, name: str) -> np.ndarray:
    """Camera response: exposed linear values ``x`` (any shape; ``(...,3)`` for "mixed") are
    clipped to [0,1] and mapped to [0,1] pixel values. Names: ``CRFS``.

    "gamma": ``x**(1/2.2)``; "srgb": the sRGB transfer function; "scurve": a sigmoid in the
    log domain normalised to [0,1]; "mixed": slightly different S-curves per RGB channel.
    """
    _check_crf(name)
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    if name == "gamma":
        y = x ** (1.0 / 2.2)
    elif name == "srgb":
        y = srgb_encode(x)
    elif name == "scurve":
        y = _scurve(x, *_SCURVE_DEFAULT)
    else:
        if x.shape[-1] != 3:
            raise LayercamError(f"CRF 'mixed' needs (...,3) input, got shape {x.shape}")
        y = np.stack([_scurve(x[..., c], *_SCURVE_MIXED[c]) for c in range(3)], axis=-1)
    return np.clip(y, 0.0, 1.0).astype(np.float32)


def crf_inverse(y: np.ndarray, name: str) -> np.ndarray:
    """Inverse of ``crf_apply``: pixel values in [0,1] -> exposed linear values in [0,1]."""
    _check_crf(name)
    y = np.clip(np.asarray(y, dtype=np.float64), 0.0, 1.0)
    if name == "gamma":
        x = y**2.2
    elif name == "srgb":
        x = srgb_decode(y)
    elif name == "scurve":
        x = _scurve_inv(y, *_SCURVE_DEFAULT)
    else:
        if y.shape[-1] != 3:
            raise LayercamError(f"CRF 'mixed' needs (...,3) input, got shape {y.shape}")
        x = np.stack([_scurve_inv(y[..., c], *_SCURVE_MIXED[c]) for c in range(3)], axis=-1)
    return np.clip(x, 0.0, 1.0).astype(np.float32)


def _expose(
    irr: np.ndarray, t: float, gain: float, crf: str, noise: float, rng: np.random.Generator | None
) -> np.ndarray:
    """Irradiance ``(...,H,W,3)`` -> 8-bit-quantised LDR float32 (noise-free when rng is None)."""
    y = crf_apply(irr * (t * gain), crf)
    if rng is not None and noise > 0:
        y = y + rng.normal(0.0, noise, size=y.shape).astype(np.float32)
    return (np.round(np.clip(y, 0.0, 1.0) * 255.0) / 255.0).astype(np.float32)


# --------------------------------------------------------------------------------------------
# HDR canvas (texture atlas) generator
# --------------------------------------------------------------------------------------------


def _fbm(rng: np.random.Generator, h: int, w: int, cells: tuple[int, ...], decay: float = 0.6):
    """Multi-scale value noise ``(h,w)`` float32, zero mean, unit std.

    ``cells``: the period in pixels of each octave (coarse to fine); amplitude ``decay**i``.
    """
    import cv2

    out = np.zeros((h, w), np.float32)
    amp = 1.0
    for c in cells:
        gh, gw = max(2, int(np.ceil(h / c)) + 1), max(2, int(np.ceil(w / c)) + 1)
        g = rng.standard_normal((gh, gw)).astype(np.float32)
        out += amp * cv2.resize(g, (w, h), interpolation=cv2.INTER_CUBIC)
        amp *= decay
    out -= out.mean()
    return out / (out.std() + 1e-8)


def _disc_alpha(h: int, w: int, cx: float, cy: float, r: float) -> np.ndarray:
    """Anti-aliased disc coverage ``(h,w)`` in [0,1]."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    d = np.sqrt((xx - cx) ** 2 + (yy - cy) ** 2)
    return np.clip(r + 0.5 - d, 0.0, 1.0)


def _blob_alpha(h: int, w: int, cx: float, cy: float, r: float, harmonics) -> np.ndarray:
    """Anti-aliased star-shaped blob, radius ``r*(1 + sum a_k sin(k theta + phi_k))``."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    dx, dy = xx - cx, yy - cy
    d = np.sqrt(dx**2 + dy**2)
    th = np.arctan2(dy, dx)
    rad = np.full_like(d, r)
    for k, a, ph in harmonics:
        rad += r * a * np.sin(k * th + ph)
    return np.clip(rad + 0.5 - d, 0.0, 1.0)


def _palette(rng: np.random.Generator, n: int) -> np.ndarray:
    """``(n,3)`` random albedo colours in [0.05, 0.9]."""
    return rng.uniform(0.05, 0.9, size=(n, 3)).astype(np.float32)


def hdr_canvas(
    size: tuple[int, int],
    rng: np.random.Generator,
    emitters: int | list[tuple[float, float]] = 4,
    emitter_stops: tuple[float, float] = (4.5, 6.0),
    shapes: int | None = None,
    illum_stops: float = 0.8,
) -> tuple[np.ndarray, dict]:
    """A textured linear HDR canvas ``(H,W,3)`` float32 and its description.

    Multi-scale noise illumination (``illum_stops`` std, in stops) times a textured albedo
    (two-colour noise mix, fine grain, flat rectangles/discs, thin dark/bright lines), plus
    bright emitters (anti-aliased discs of radius 2-5 px with a faint glow) whose core is
    ``emitter_stops`` stops above the background median, so a single exposure clips them.

    emitters: a count (random positions) or a list of ``(x, y)`` centres.
    Returns ``(canvas, info)``; info has ``median`` (background median luminance) and
    ``emitters`` (list of dicts with ``x, y, r, stops``).
    """
    import cv2

    h, w = int(size[0]), int(size[1])
    if shapes is None:
        shapes = max(6, int(h * w / 1500))
    # albedo: two-colour blend + fine grain
    cols = _palette(rng, 2)
    mix = _sigmoid(1.5 * _fbm(rng, h, w, (48, 24, 12)))[..., None]
    alb = cols[0] * mix + cols[1] * (1.0 - mix)
    grain = _fbm(rng, h, w, (6, 3, 1.5), decay=0.7)
    alb = alb * np.exp(0.35 * grain)[..., None]
    # shapes: flat-coloured rectangles, discs, lines (strong edges)
    shp_cols = _palette(rng, shapes)
    for i in range(shapes):
        kind = rng.integers(0, 3)
        cx, cy = rng.uniform(0, w), rng.uniform(0, h)
        s = rng.uniform(4, max(6.0, min(h, w) / 6))
        if kind == 0:
            a = np.zeros((h, w), np.float32)
            x0, y0 = int(cx - s), int(cy - s * rng.uniform(0.4, 1.0))
            x1, y1 = int(cx + s), int(cy + s * rng.uniform(0.4, 1.0))
            cv2.rectangle(a, (x0, y0), (x1, y1), 1.0, -1)
        elif kind == 1:
            a = _disc_alpha(h, w, cx, cy, s * 0.8)
        else:
            a = np.zeros((h, w), np.float32)
            ang = rng.uniform(0, np.pi)
            dx, dy = np.cos(ang) * s * 3, np.sin(ang) * s * 3
            cv2.line(a, (int(cx - dx), int(cy - dy)), (int(cx + dx), int(cy + dy)), 1.0,
                     int(rng.integers(1, 3)))
        a = a[..., None]
        alb = alb * (1 - a) + shp_cols[i] * a
    alb = np.clip(alb, 0.02, 1.0)
    illum = np.exp2(illum_stops * _fbm(rng, h, w, (96, 48, 24)))[..., None]
    canvas = (alb * illum).astype(np.float32)
    lum = luma(canvas, REC709)
    med = float(np.median(lum))
    # emitters
    if isinstance(emitters, (int, np.integer)):
        centres = [(rng.uniform(8, w - 8), rng.uniform(8, h - 8)) for _ in range(int(emitters))]
    else:
        centres = [(float(x), float(y)) for x, y in emitters]
    info_em = []
    for cx, cy in centres:
        r = float(rng.uniform(2.0, 5.0))
        stops = float(rng.uniform(*emitter_stops))
        col = np.array([1.0, rng.uniform(0.75, 0.95), rng.uniform(0.5, 0.9)], np.float32)
        col = col[rng.permutation(3)] if rng.uniform() < 0.3 else col
        core = _disc_alpha(h, w, cx, cy, r)
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        glow = np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * (2.5 * r) ** 2))
        prof = core + 0.04 * glow
        canvas += (med * 2.0**stops) * prof[..., None] * col
        info_em.append({"x": cx, "y": cy, "r": r, "stops": stops})
    return canvas.astype(np.float32), {"median": med, "emitters": info_em}


# --------------------------------------------------------------------------------------------
# Geometry helpers
# --------------------------------------------------------------------------------------------


def _affine(cx: float, cy: float, s: float, h: int, w: int, rot: float = 0.0) -> np.ndarray:
    """``(2,3)`` frame->canvas map: frame centre -> ``(cx,cy)``, scale ``s``, rotation."""
    c, sn = np.cos(rot) * s, np.sin(rot) * s
    lin = np.array([[c, -sn], [sn, c]])
    ctr = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    return np.concatenate([lin, (np.array([cx, cy]) - lin @ ctr)[:, None]], axis=1)


def _warp(canvas: np.ndarray, a: np.ndarray, h: int, w: int, zero_border: bool = False):
    """Sample ``canvas`` at ``a @ (x,y,1)`` for every frame pixel (bilinear); outside the
    canvas: reflection, or zeros when ``zero_border``."""
    import cv2

    border = cv2.BORDER_CONSTANT if zero_border else cv2.BORDER_REFLECT_101
    return cv2.warpAffine(
        canvas, a.astype(np.float64), (w, h),
        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=border, borderValue=0,
    )


def _h3(a: np.ndarray) -> np.ndarray:
    return np.concatenate([a, [[0.0, 0.0, 1.0]]], axis=0)


def _affine_flow(a0: np.ndarray, a1: np.ndarray, h: int, w: int) -> np.ndarray:
    """Flow ``(h,w,2)`` of points fixed in the canvas from frame map a0 to frame map a1."""
    m = np.linalg.inv(_h3(a1)) @ _h3(a0)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    x1 = m[0, 0] * xx + m[0, 1] * yy + m[0, 2]
    y1 = m[1, 0] * xx + m[1, 1] * yy + m[1, 2]
    return np.stack([x1 - xx, y1 - yy], axis=-1).astype(np.float32)


def _pan_path(rng, frames, h, w, speed, zoom):
    """Centres ``(T,2)`` (relative, start at 0) and scales ``(T,)`` of a smooth pan."""
    ang = rng.uniform(0, 2 * np.pi)
    v = rng.uniform(*speed)
    d = np.array([np.cos(ang), np.sin(ang)])
    perp = np.array([-d[1], d[0]])
    t = np.arange(frames, dtype=np.float64)
    wob_a, wob_p, wob_ph = rng.uniform(0.5, 2.0), rng.uniform(10, 20), rng.uniform(0, 2 * np.pi)
    wob = wob_a * (np.sin(2 * np.pi * t / wob_p + wob_ph) - np.sin(wob_ph))
    ctr = v * t[:, None] * d + wob[:, None] * perp
    scale = 1.0 + zoom * (t / max(frames - 1, 1))
    return ctr, scale


def _canvas_for_path(ctr, scale, h, w, margin, extra=0.0):
    """Canvas size and the offset to add to relative centres so every crop fits."""
    half = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    ext = scale[:, None] * half[None] + extra
    lo = (ctr - ext).min(axis=0) - margin
    hi = (ctr + ext).max(axis=0) + margin
    cw, ch = int(np.ceil(hi[0] - lo[0])) + 1, int(np.ceil(hi[1] - lo[1])) + 1
    return (ch, cw), -lo


def _emitters_along(rng, ctr_abs, h, w, n):
    """``n`` emitter centres near the camera path so that most frames see some."""
    idx = np.linspace(0, len(ctr_abs) - 1, n) if n > 0 else []
    out = []
    for i in idx:
        c = ctr_abs[int(round(i))]
        out.append((c[0] + rng.uniform(-0.35, 0.35) * w, c[1] + rng.uniform(-0.35, 0.35) * h))
    return out


def _check_common(frames: int, size, crf: str, noise: float) -> tuple[int, int]:
    if int(frames) < 1:
        raise LayercamError(f"frames must be >= 1, got {frames}")
    if len(size) != 2 or min(size) < 8:
        raise LayercamError(f"size must be (H, W) with both >= 8, got {size}")
    _check_crf(crf)
    if noise < 0:
        raise LayercamError(f"noise must be >= 0, got {noise}")
    return int(size[0]), int(size[1])


def _alternating(frames: int, ev_step: float) -> np.ndarray:
    return np.where(np.arange(frames) % 2 == 0, 1.0, 2.0**ev_step).astype(np.float64)


def _make_clip(frames: np.ndarray, family: str, names=None) -> Clip:
    t = frames.shape[0]
    names = names or [f"{i:05d}" for i in range(t)]
    return Clip(frames=frames.astype(np.float32), source=f"synthetic:{family}", names=names,
                fps=24.0, bit_depth=8, exif_exposures=None, meta={"kind": "synthetic"})


# --------------------------------------------------------------------------------------------
# Family: pan_hdr
# --------------------------------------------------------------------------------------------


def pan_hdr(
    frames: int = 24,
    size: tuple[int, int] = (128, 128),
    ev_step: float = 3.0,
    crf: str = "srgb",
    noise: float = 0.005,
    seed: int = 0,
    zoom: float = 0.05,
    speed: tuple[float, float] = (1.5, 3.0),
    emitters: int | None = None,
) -> SynthScene:
    """A camera panning (``speed`` px/frame, sub-pixel, with a small wobble) and zooming
    (scale ``1 -> 1+zoom``) across an HDR canvas, with alternating exposures: frame 0 at
    ``t=1``, frame 1 at ``t=2**ev_step``, ... The gain puts the brightest emitter at 0.9 in the
    low exposure (emitters unclipped there) so the high exposure clips them and lifts shadows.
    ``size`` is ``(H, W)``.
    """
    h, w = _check_common(frames, size, crf, noise)
    rng = np.random.default_rng(seed)
    ctr, scale = _pan_path(rng, frames, h, w, speed, zoom)
    csize, off = _canvas_for_path(ctr, scale, h, w, margin=8)
    ctr_abs = ctr + off
    n_em = emitters if emitters is not None else max(3, int(round(csize[0] * csize[1] / 6000)))
    canvas, info = hdr_canvas(csize, rng, emitters=_emitters_along(rng, ctr_abs, h, w, n_em))
    gain = 0.9 / float(canvas.max())
    aff = np.stack([_affine(ctr_abs[t, 0], ctr_abs[t, 1], scale[t], h, w) for t in range(frames)])
    hdr = np.stack([_warp(canvas, aff[t], h, w) for t in range(frames)])
    times = _alternating(frames, ev_step)
    ldr = np.stack([_expose(hdr[t], times[t], gain, crf, noise, rng) for t in range(frames)])
    meta = {
        "family": "pan_hdr", "seed": seed, "ev_step": ev_step, "noise": noise, "zoom": zoom,
        "gain": gain, "frame_affine": aff.astype(np.float32), "canvas_shape": csize,
        "canvas_median": info["median"], "emitters": info["emitters"],
    }
    return SynthScene(_make_clip(ldr, "pan_hdr"), times, hdr.astype(np.float32), crf, None, meta)


# --------------------------------------------------------------------------------------------
# Family: static_single
# --------------------------------------------------------------------------------------------


def static_single(
    frames: int = 8,
    size: tuple[int, int] = (64, 64),
    crf: str = "srgb",
    seed: int = 0,
    noise: float = 0.005,
    emitters: int = 0,
) -> SynthScene:
    """A static camera, one exposure (``t=1``), sharp frames differing only by noise.

    No emitters by default, so the HDR is recoverable from the single exposure; the gain maps
    the background median to 0.18.
    """
    h, w = _check_common(frames, size, crf, noise)
    rng = np.random.default_rng(seed)
    canvas, info = hdr_canvas((h + 16, w + 16), rng, emitters=emitters)
    gain = 0.18 / info["median"]
    a = _affine(8 + (w - 1) / 2.0, 8 + (h - 1) / 2.0, 1.0, h, w)
    img = _warp(canvas, a, h, w)
    hdr = np.repeat(img[None], frames, axis=0)
    times = np.ones(frames, np.float64)
    ldr = np.stack([_expose(hdr[t], 1.0, gain, crf, noise, rng) for t in range(frames)])
    meta = {
        "family": "static_single", "seed": seed, "noise": noise, "gain": gain,
        "frame_affine": np.repeat(a[None], frames, 0).astype(np.float32),
        "canvas_median": info["median"], "emitters": info["emitters"],
    }
    return SynthScene(_make_clip(ldr, "static_single"), times, hdr.astype(np.float32), crf,
                      None, meta)


# --------------------------------------------------------------------------------------------
# Family: moving_object
# --------------------------------------------------------------------------------------------


def moving_object(
    frames: int = 24,
    size: tuple[int, int] = (128, 128),
    ev_step: float = 3.0,
    crf: str = "srgb",
    noise: float = 0.005,
    seed: int = 0,
    zoom: float = 0.0,
    speed: tuple[float, float] = (1.0, 2.0),
    object_speed: tuple[float, float] = (2.5, 4.0),
    object_radius: float = 0.2,
) -> SynthScene:
    """``pan_hdr``-like background plus a textured blob (radius ``object_radius*min(H,W)``)
    moving on a Lissajous path in the frame (staying inside it) and rotating slowly.

    ``fg_mask`` is the blob's coverage > 0.5. ``meta["object_affine"]`` ``(T,2,3)`` maps
    frame pixels to the object's texture coordinates.
    """
    h, w = _check_common(frames, size, crf, noise)
    rng = np.random.default_rng(seed)
    ctr, scale = _pan_path(rng, frames, h, w, speed, zoom)
    csize, off = _canvas_for_path(ctr, scale, h, w, margin=8)
    ctr_abs = ctr + off
    n_em = max(3, int(round(csize[0] * csize[1] / 6000)))
    canvas, info = hdr_canvas(csize, rng, emitters=_emitters_along(rng, ctr_abs, h, w, n_em))
    # object texture (own palette, a bit brighter than the background) and shape
    r = float(object_radius) * min(h, w)
    osz = int(np.ceil(2 * r * 1.4)) + 4
    otex, _ = hdr_canvas((osz, osz), rng, emitters=0, shapes=4, illum_stops=0.4)
    otex = otex * (info["median"] * 2.0 ** rng.uniform(0.5, 1.5) / float(np.median(otex)))
    harm = [(2, rng.uniform(0.05, 0.15), rng.uniform(0, 2 * np.pi)),
            (3, rng.uniform(0.03, 0.1), rng.uniform(0, 2 * np.pi))]
    oc = (osz - 1) / 2.0
    oalpha = _blob_alpha(osz, osz, oc, oc, r, harm)
    # object path: Lissajous in frame coordinates, slow rotation
    t = np.arange(frames, dtype=np.float64)
    amp = np.array([max(1.0, (w - 1) / 2.0 - r * 1.1), max(1.0, (h - 1) / 2.0 - r * 1.1)])
    v = rng.uniform(*object_speed)
    om = v / amp * np.array([1.0, rng.uniform(0.5, 0.9)])
    ph = rng.uniform(0, 2 * np.pi, size=2)
    oc_path = np.array([(w - 1) / 2.0, (h - 1) / 2.0]) + amp * np.sin(om * t[:, None] + ph)
    rot = rng.uniform(-0.03, 0.03) * t
    aff = np.stack([_affine(ctr_abs[i, 0], ctr_abs[i, 1], scale[i], h, w) for i in range(frames)])
    oaff = []
    for i in range(frames):
        c, s = np.cos(-rot[i]), np.sin(-rot[i])
        lin = np.array([[c, -s], [s, c]])
        oaff.append(np.concatenate([lin, (np.array([oc, oc]) - lin @ oc_path[i])[:, None]], 1))
    oaff = np.stack(oaff)
    hdr, masks = [], []
    for i in range(frames):
        bg = _warp(canvas, aff[i], h, w)
        fg = _warp(otex, oaff[i], h, w)
        al = np.clip(_warp(oalpha, oaff[i], h, w, zero_border=True), 0, 1)[..., None]
        hdr.append(al * fg + (1 - al) * bg)
        masks.append(al[..., 0] > 0.5)
    hdr = np.stack(hdr).astype(np.float32)
    gain = 0.9 / float(hdr.max())
    times = _alternating(frames, ev_step)
    ldr = np.stack([_expose(hdr[i], times[i], gain, crf, noise, rng) for i in range(frames)])
    meta = {
        "family": "moving_object", "seed": seed, "ev_step": ev_step, "noise": noise,
        "zoom": zoom, "gain": gain, "frame_affine": aff.astype(np.float32),
        "object_affine": oaff.astype(np.float32), "object_centre": oc_path.astype(np.float32),
        "object_radius": r, "canvas_median": info["median"], "emitters": info["emitters"],
    }
    return SynthScene(_make_clip(ldr, "moving_object"), times, hdr, crf, np.stack(masks), meta)


# --------------------------------------------------------------------------------------------
# Family: shake_blur
# --------------------------------------------------------------------------------------------


def _shake_curve(rng: np.random.Generator, length: float, n: int) -> np.ndarray:
    """``(n,2)`` offsets along a smooth random curve at s in [-1/2, 1/2], zero at s=0, with
    largest pairwise distance ``length`` (px)."""
    s = np.linspace(-0.5, 0.5, n)
    ang = rng.uniform(0, 2 * np.pi)
    a = np.array([np.cos(ang), np.sin(ang)])
    b = rng.normal(0, 1.2, 2)
    c = rng.normal(0, 1.5, 2)
    p = s[:, None] * a + (s**2)[:, None] * b + (s**3)[:, None] * c
    ext = np.max(np.linalg.norm(p[:, None] - p[None], axis=-1))
    return p * (length / max(ext, 1e-9))


def _splat_kernel(offsets: np.ndarray, m: int) -> np.ndarray:
    """Correlation kernel ``(2m+1,2m+1)``: ``blurred(x) = sum k[m+dy,m+dx] sharp(x+(dx,dy))``."""
    k = np.zeros((2 * m + 1, 2 * m + 1), np.float64)
    for dx, dy in offsets:
        x, y = m + dx, m + dy
        x0, y0 = int(np.floor(x)), int(np.floor(y))
        fx, fy = x - x0, y - y0
        for yy, wy in ((y0, 1 - fy), (y0 + 1, fy)):
            for xx, wx in ((x0, 1 - fx), (x0 + 1, fx)):
                if 0 <= yy <= 2 * m and 0 <= xx <= 2 * m:
                    k[yy, xx] += wx * wy
    return (k / max(k.sum(), 1e-12)).astype(np.float32)


def shake_blur(
    frames: int = 16,
    size: tuple[int, int] = (128, 128),
    max_blur_px: float = 8.0,
    exposures: str = "single",
    ev_step: float = 2.0,
    crf: str = "srgb",
    noise: float = 0.005,
    seed: int = 0,
    speed: tuple[float, float] = (0.5, 1.5),
) -> SynthScene:
    """Camera-shake motion blur: each frame is the mean, in linear irradiance, of 9-15
    sub-frame renders along a random smooth trajectory around the frame's pose (a slow pan).

    Blur lengths (largest extent of the trajectory, px) are a shuffled ``linspace(0.2,
    max_blur_px, T)``: some frames sharp-ish, some strongly blurred. ``hdr`` and ``sharp_ldr``
    (noise-free) are the sharp frames at the trajectory's mid point (its pose). exposures:
    "single" (all ``t=1``, background median at 0.18) or "alternating" (``1, 2**ev_step``).
    meta: ``blur_length`` (T,), ``trajectories`` (list of (n,2) pixel offsets of the content
    sample point), ``kernels`` (T,2m+1,2m+1) correlation kernels (see ``_splat_kernel``).
    """
    h, w = _check_common(frames, size, crf, noise)
    if exposures not in ("single", "alternating"):
        raise LayercamError(f"exposures must be 'single' or 'alternating', got {exposures!r}")
    if max_blur_px < 0:
        raise LayercamError(f"max_blur_px must be >= 0, got {max_blur_px}")
    rng = np.random.default_rng(seed)
    ctr, scale = _pan_path(rng, frames, h, w, speed, 0.0)
    csize, off = _canvas_for_path(ctr, scale, h, w, margin=8, extra=max_blur_px + 2)
    ctr_abs = ctr + off
    n_em = max(3, int(round(csize[0] * csize[1] / 6000)))
    canvas, info = hdr_canvas(csize, rng, emitters=_emitters_along(rng, ctr_abs, h, w, n_em))
    lengths = rng.permutation(np.linspace(0.2, max_blur_px, frames))
    aff = np.stack([_affine(ctr_abs[t, 0], ctr_abs[t, 1], 1.0, h, w) for t in range(frames)])
    m = int(np.ceil(max_blur_px)) + 1
    sharp, blurred, trajs, kernels = [], [], [], []
    for t in range(frames):
        n_sub = int(np.clip(np.ceil(1.5 * lengths[t]) + 1, 9, 15))
        p = _shake_curve(rng, float(lengths[t]), n_sub)
        acc = np.zeros((h, w, 3), np.float32)
        for dx, dy in p:
            a = aff[t].copy()
            a[:, 2] += (dx, dy)
            acc += _warp(canvas, a, h, w)
        blurred.append(acc / n_sub)
        sharp.append(_warp(canvas, aff[t], h, w))
        trajs.append(p.astype(np.float32))
        kernels.append(_splat_kernel(p, m))
    sharp = np.stack(sharp).astype(np.float32)
    blurred = np.stack(blurred).astype(np.float32)
    if exposures == "single":
        times = np.ones(frames, np.float64)
        gain = 0.18 / info["median"]
    else:
        times = _alternating(frames, ev_step)
        gain = 0.9 / float(canvas.max())
    ldr = np.stack([_expose(blurred[t], times[t], gain, crf, noise, rng) for t in range(frames)])
    sharp_ldr = np.stack([_expose(sharp[t], times[t], gain, crf, 0.0, None) for t in range(frames)])
    meta = {
        "family": "shake_blur", "seed": seed, "noise": noise, "exposures": exposures,
        "ev_step": ev_step if exposures == "alternating" else 0.0, "gain": gain,
        "max_blur_px": max_blur_px, "blur_length": lengths.astype(np.float32),
        "trajectories": trajs, "kernels": np.stack(kernels),
        "frame_affine": aff.astype(np.float32), "canvas_median": info["median"],
        "emitters": info["emitters"],
    }
    return SynthScene(_make_clip(ldr, "shake_blur"), times, sharp, crf, None, meta,
                      sharp_ldr=sharp_ldr)


# --------------------------------------------------------------------------------------------
# Family: mfme_stack
# --------------------------------------------------------------------------------------------


def _pillbox(radius: float) -> np.ndarray:
    """Normalised anti-aliased disc kernel of the given radius (``[[1]]`` below 0.25 px)."""
    if radius < 0.25:
        return np.ones((1, 1), np.float32)
    m = int(np.ceil(radius + 0.5))
    k = _disc_alpha(2 * m + 1, 2 * m + 1, m, m, radius)
    return (k / k.sum()).astype(np.float32)


def _filter(img: np.ndarray, k: np.ndarray) -> np.ndarray:
    import cv2

    if k.shape == (1, 1):
        return img.copy()
    return cv2.filter2D(img, -1, k, borderType=cv2.BORDER_REFLECT_101)


def mfme_stack(
    size: tuple[int, int] = (128, 128),
    focus_settings: int = 3,
    exposures_ev: tuple[float, ...] = (0.0, 2.0, 4.0),
    planes: int = 3,
    max_blur_px: float = 5.0,
    crf: str = "srgb",
    noise: float = 0.005,
    seed: int = 0,
) -> SynthScene:
    """A static multi-focus multi-exposure stack of ``planes`` (2 or 3) textured depth planes
    (far background at depth 4, a blob at 2, a disc at 1 for 3 planes).

    Defocus: a pillbox of radius ``c*|1/depth - 1/focus|`` (``c`` such that the largest is
    ``max_blur_px``) applied per plane to linear irradiance and alpha, composited back to
    front. Focus distances are spread evenly in inverse depth between the nearest and the
    farthest plane (the plane depths themselves when ``focus_settings == planes``).

    Images are ordered FOCUS-MAJOR: image ``i`` has focus ``i // E`` and exposure
    ``i % E`` (``E = len(exposures_ev)``); ``meta["focus_index"]``, ``meta["exposure_index"]``
    and ``meta["ev"]`` give them per image, ``exposure_times = 2**ev``. The gain puts the
    brightest all-in-focus pixel at 0.9 for EV 0 (i.e. ``min(exposures_ev)`` is the low one).
    ``allfocus_hdr`` ``(H,W,3)``; ``hdr`` repeats it per image; ``sharp_ldr`` is the
    noise-free all-in-focus LDR at each image's exposure; ``meta["depth"]`` ``(H,W)``.
    """
    h, w = _check_common(1, size, crf, noise)
    if planes not in (2, 3):
        raise LayercamError(f"planes must be 2 or 3, got {planes}")
    if int(focus_settings) < 1 or len(exposures_ev) < 1:
        raise LayercamError("need at least one focus setting and one exposure")
    rng = np.random.default_rng(seed)
    depths = [4.0, 2.0, 1.0][:planes] if planes == 3 else [4.0, 1.0]
    # layers back to front: (irradiance, alpha)
    back, info = hdr_canvas((h, w), rng, emitters=max(2, int(round(h * w / 5000))))
    layers = [(back, np.ones((h, w), np.float32))]
    med = info["median"]
    for li in range(1, planes):
        tex, _ = hdr_canvas((h, w), rng, emitters=0, shapes=4, illum_stops=0.5)
        tex = tex * (med * 2.0 ** rng.uniform(-0.5, 1.0) / float(np.median(tex)))
        if li == planes - 1:  # nearest: a disc
            al = _disc_alpha(h, w, rng.uniform(0.3, 0.7) * w, rng.uniform(0.3, 0.7) * h,
                             rng.uniform(0.18, 0.25) * min(h, w))
        else:  # middle: a large blob on one side
            cx = rng.choice([0.25, 0.75]) * w
            al = _blob_alpha(h, w, cx, rng.uniform(0.3, 0.7) * h, 0.3 * min(h, w),
                             [(2, 0.15, rng.uniform(0, 6.3)), (3, 0.08, rng.uniform(0, 6.3))])
        layers.append((tex, al))
    inv_d = 1.0 / np.array(depths)
    n_f = int(focus_settings)
    inv_f = inv_d.copy() if n_f == planes else np.linspace(inv_d.min(), inv_d.max(), n_f)
    c = max_blur_px / max(np.max(np.abs(inv_d[:, None] - inv_f[None, :])), 1e-9)
    radii = c * np.abs(inv_d[:, None] - inv_f[None, :])  # (planes, focus)

    def compose(fi: int | None) -> np.ndarray:
        out = np.zeros((h, w, 3), np.float32)
        for li, (tex, al) in enumerate(layers):
            k = _pillbox(0.0 if fi is None else float(radii[li, fi]))
            a = _filter(al, k)
            out = _filter(tex * al[..., None], k) + (1.0 - a[..., None]) * out
        return out

    allfocus = compose(None)
    blurred = [compose(f) for f in range(n_f)]
    depth = np.full((h, w), depths[0], np.float32)
    for li in range(1, planes):
        depth[layers[li][1] > 0.5] = depths[li]
    evs = np.asarray(exposures_ev, np.float64)
    gain = 0.9 / float(allfocus.max()) / 2.0 ** evs.min()
    n_e = len(evs)
    imgs, f_idx, e_idx, ev_list, names, sharp_ldr = [], [], [], [], [], []
    for f in range(n_f):
        for e in range(n_e):
            t = 2.0 ** evs[e]
            imgs.append(_expose(blurred[f], t, gain, crf, noise, rng))
            sharp_ldr.append(_expose(allfocus, t, gain, crf, 0.0, None))
            f_idx.append(f)
            e_idx.append(e)
            ev_list.append(float(evs[e]))
            names.append(f"f{f}_ev{evs[e]:+g}")
    n = len(imgs)
    times = 2.0 ** np.array(ev_list)
    meta = {
        "family": "mfme_stack", "seed": seed, "noise": noise, "gain": gain,
        "order": "focus-major", "focus_index": np.array(f_idx), "exposure_index": np.array(e_idx),
        "ev": np.array(ev_list), "plane_depths": depths, "focus_depths": (1.0 / inv_f).tolist(),
        "blur_radius": radii.astype(np.float32), "depth": depth, "max_blur_px": max_blur_px,
        "canvas_median": med, "emitters": info["emitters"],
    }
    return SynthScene(
        _make_clip(np.stack(imgs), "mfme_stack", names), times,
        np.repeat(allfocus[None], n, 0).astype(np.float32), crf, None, meta,
        sharp_ldr=np.stack(sharp_ldr), allfocus_hdr=allfocus.astype(np.float32),
    )


# --------------------------------------------------------------------------------------------
# Ground-truth flow and dispatcher
# --------------------------------------------------------------------------------------------


def true_flow(scene: SynthScene) -> np.ndarray:
    """Ground-truth forward flow ``(T-1,H,W,2)`` (x,y px; frame t -> t+1) of the frames' poses.

    Background pixels move with ``meta["frame_affine"]``; for ``moving_object`` the pixels
    under ``fg_mask[t]`` move with ``meta["object_affine"]``. Static families (no affine) give
    zeros. For ``shake_blur`` this is the motion of the mid-exposure poses.
    """
    t, h, w = scene.hdr.shape[:3]
    out = np.zeros((max(t - 1, 0), h, w, 2), np.float32)
    aff = scene.meta.get("frame_affine")
    if aff is None:
        return out
    oaff = scene.meta.get("object_affine")
    for i in range(t - 1):
        out[i] = _affine_flow(aff[i], aff[i + 1], h, w)
        if oaff is not None and scene.fg_mask is not None:
            of = _affine_flow(oaff[i], oaff[i + 1], h, w)
            out[i][scene.fg_mask[i]] = of[scene.fg_mask[i]]
    return out


FAMILIES = ["pan_hdr", "static_single", "moving_object", "shake_blur", "mfme_stack"]

_FAMILY_FUNCS = {
    "pan_hdr": pan_hdr,
    "static_single": static_single,
    "moving_object": moving_object,
    "shake_blur": shake_blur,
    "mfme_stack": mfme_stack,
}


def make(family: str, **kw) -> SynthScene:
    """Render the named family (``FAMILIES``) with keyword arguments passed through."""
    if family not in _FAMILY_FUNCS:
        raise LayercamError(
            f"unknown synthetic family {family!r}; choose one of {', '.join(FAMILIES)}"
        )
    import inspect

    fn = _FAMILY_FUNCS[family]
    bad = sorted(set(kw) - set(inspect.signature(fn).parameters))
    if bad:
        raise LayercamError(f"synthetic family {family!r} has no parameter(s) {', '.join(bad)}")
    return fn(**kw)
