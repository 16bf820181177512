"""Families of moving-camera video: ``pan_hdr``, ``static_single``, ``moving_object``, and the
ground-truth flow of their frames (:func:`true_flow`)."""

from __future__ import annotations

import numpy as np

from layercam.synth.camera import SynthScene, _alternating, _check_common, _expose, _make_clip
from layercam.synth.canvas import (_affine, _affine_flow, _blob_alpha, _canvas_for_path,
                                   _emitters_along, _pan_path, _warp, hdr_canvas)


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
    ``size`` is ``(H, W)``. :func:`pan_hdr_frames` gives the same frames one at a time.
    """
    meta, times, each = pan_hdr_frames(frames, size, ev_step, crf, noise, seed, zoom, speed, emitters)
    pairs = list(each)
    hdr = np.stack([p[0] for p in pairs])
    ldr = np.stack([p[1] for p in pairs])
    return SynthScene(_make_clip(ldr, "pan_hdr"), times, hdr.astype(np.float32), crf, None, meta)


def pan_hdr_frames(
    frames: int = 24,
    size: tuple[int, int] = (128, 128),
    ev_step: float = 3.0,
    crf: str = "srgb",
    noise: float = 0.005,
    seed: int = 0,
    zoom: float = 0.05,
    speed: tuple[float, float] = (1.5, 3.0),
    emitters: int | None = None,
):
    """:func:`pan_hdr` one frame at a time, for clips too large to hold (1080p): returns
    ``(meta, exposure_times, frames)`` where ``frames`` yields ``(hdr (H,W,3), ldr (H,W,3))`` float32
    per frame, bit-identical to ``pan_hdr``'s (the noise is drawn in the same order)."""
    h, w = _check_common(frames, size, crf, noise)
    rng = np.random.default_rng(seed)
    ctr, scale = _pan_path(rng, frames, h, w, speed, zoom)
    csize, off = _canvas_for_path(ctr, scale, h, w, margin=8)
    ctr_abs = ctr + off
    n_em = emitters if emitters is not None else max(3, int(round(csize[0] * csize[1] / 6000)))
    canvas, info = hdr_canvas(csize, rng, emitters=_emitters_along(rng, ctr_abs, h, w, n_em))
    gain = 0.9 / float(canvas.max())
    aff = np.stack([_affine(ctr_abs[t, 0], ctr_abs[t, 1], scale[t], h, w) for t in range(frames)])
    times = _alternating(frames, ev_step)
    meta = {
        "family": "pan_hdr", "seed": seed, "ev_step": ev_step, "noise": noise, "zoom": zoom,
        "gain": gain, "frame_affine": aff.astype(np.float32), "canvas_shape": csize,
        "canvas_median": info["median"], "emitters": info["emitters"],
    }

    def each():
        for t in range(frames):
            hdr = _warp(canvas, aff[t], h, w)
            yield hdr, _expose(hdr, times[t], gain, crf, noise, rng)

    return meta, times, each()


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
