"""Family ``mfme_stack``: a static multi-focus multi-exposure stack of textured depth planes."""

from __future__ import annotations

import numpy as np

from layercam.core.errors import LayercamError
from layercam.synth.camera import SynthScene, _check_common, _expose, _make_clip
from layercam.synth.canvas import _blob_alpha, _disc_alpha, hdr_canvas


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
