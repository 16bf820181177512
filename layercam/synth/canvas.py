"""What the synthetic scenes are made of: an HDR canvas (texture atlas with emitters), shapes, and
the camera paths and affine maps that cut frames out of it."""

from __future__ import annotations

import numpy as np

from layercam.core.colour import REC709, luma
from layercam.synth.camera import _sigmoid


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
