"""Rendering a trained model with the camera dropped (sharp linear HDR) or kept (LDR re-renders),
and the display tonemap used for previews."""

from __future__ import annotations

import numpy as np
import torch

from layercam.core.colour import REC709, luma, srgb_encode
from layercam.scene.coords import pixel_grid


FRAME_OUTPUTS = ("hdr", "log2_r", "layers", "ldr", "uv", "alpha")


@torch.no_grad()
def render_frame(model, t: int, hw: tuple[int, int], what=("hdr",), *, log2_dt: float | None = None,
                 blur: bool = False, t_blur: float | None = None, centred: bool = False,
                 stride: int = 1, chunk: int = 65536) -> dict:
    """Frame ``t`` of a trained model at ``hw = (H, W)``, rendered in chunks of ``chunk`` pixels on
    the model's device (``chunk / K`` with a ``K``-sample blur patch); the one full-frame renderer of
    the exports, ``render``, ``edit``, the notebook and the benchmark's probe. ``stride``: every
    ``stride``-th pixel of every ``stride``-th row only, from pixel (0, 0) (outputs of
    ``(ceil(H / stride), ceil(W / stride))``).

    ``what`` names the outputs, returned as float32 numpy arrays:

    * ``"hdr"``: linear irradiance ``2^log2_r (H, W, 3)``, the camera dropped; ``"log2_r"``: its log2;
    * ``"layers"``: each layer's log2 irradiance ``[L x (H, W, 3)]`` (composite them with
      :func:`composite_layers`);
    * ``"ldr"``: ``(H, W, 3)`` through the tone mapper at the frame's own exposure, or at
      ``log2_dt``; ``blur`` applies the blur generator first, with the blur of the fractional image
      index ``t_blur`` when given (focus between training images), each PSF moved onto its pixel
      with ``centred`` (its shape without its shift: the sharp export's check);
    * ``"uv"``: each layer's atlas coordinates ``[L x (H, W, 2)]``; ``"alpha"``: the foreground's
      opacity ``(H, W)`` (None for one layer). Asked for alone, they skip the atlases and camera.
    """
    what = (what,) if isinstance(what, str) else tuple(what)
    unknown = set(what) - set(FRAME_OUTPUTS)
    if unknown:
        raise ValueError(f"unknown render output(s) {sorted(unknown)} (one of {', '.join(FRAME_OUTPUTS)})")
    h, w = hw
    dev = next(model.parameters()).device
    geometry_only = set(what) <= {"uv", "alpha"}
    use_blur = "ldr" in what and blur and model.blur is not None
    step = max(1, chunk // model.blur.K) if use_blur else chunk
    xy_all = pixel_grid(h, w, dev)
    if stride > 1:
        xy_all = xy_all.view(h, w, 2)[::stride, ::stride].reshape(-1, 2)
        h, w = -(-h // stride), -(-w // stride)
    parts: dict = {k: [] for k in what}
    for s in range(0, xy_all.shape[0], step):
        xy = xy_all[s : s + step]
        tt = torch.full((xy.shape[0],), int(t), dtype=torch.long, device=dev)
        out = model.scene.mappings(xy, tt) if geometry_only else model.scene(xy, tt)
        got = {"uv": lambda: torch.stack(out["uv"], 0), "alpha": lambda: out["alpha"], "log2_r": lambda: out["log2_r"],
               "hdr": lambda: torch.exp2(out["log2_r"]), "layers": lambda: torch.stack(out["layer_log2_r"], 0),
               "ldr": lambda: _through_camera(model, xy, tt, out, log2_dt, use_blur, t_blur, centred)}
        for k in what:
            v = got[k]()
            if v is not None:
                parts[k].append(v.float().cpu())
    shapes = {"hdr": (h, w, 3), "log2_r": (h, w, 3), "ldr": (h, w, 3), "alpha": (h, w),
              "uv": (-1, h, w, 2), "layers": (-1, h, w, 3)}
    res = {}
    for k, v in parts.items():
        if not v:
            res[k] = None  # alpha of a one-layer scene
            continue
        arr = torch.cat(v, 1 if k in ("uv", "layers") else 0).view(*shapes[k]).numpy()
        res[k] = list(arr) if k in ("uv", "layers") else arr
    return res


def _through_camera(model, xy, t, out: dict, log2_dt: float | None, blur: bool,
                    t_blur: float | None, centred: bool = False) -> torch.Tensor:
    """The scene output ``out`` at ``xy, t`` as the camera records it: ``(N, 3)``."""
    log2_r = out["log2_r"]
    if blur:
        tb = None if t_blur is None else torch.full((xy.shape[0],), float(t_blur), device=xy.device)
        log2_r = model.blur(model.scene, xy, t, out, t_blur=tb, centre=centred)
    dt = model.exposure(t) if log2_dt is None else torch.full_like(log2_r[:, :1], float(log2_dt))
    return model.tone_map(log2_r, dt)


def display_stats(lum: np.ndarray) -> dict:
    """The clip-wide statistics of :func:`tonemap_display` from luminances (any shape; non-finite
    values left out): log-average luminance and white point (99.9th percentile)."""
    lum_f = lum[np.isfinite(lum)]
    lavg = float(np.exp(np.mean(np.log(np.maximum(lum_f, 1e-8))))) if lum_f.size else 1.0
    white = float(np.percentile(lum_f, 99.9)) / max(lavg, 1e-12) * 0.18 if lum_f.size else 1.0
    return {"log_avg": lavg, "white": max(white, 1e-3)}


def tonemap_display(hdr: np.ndarray, stats: dict | None = None) -> tuple[np.ndarray, dict]:
    """Global Reinhard (extended) + sRGB for display. ``(..., 3)`` linear -> same shape in ``[0, 1]``.

    ``stats`` (log-average luminance and white point) computed over the whole clip once and reused
    for every frame, so that the preview does not flicker.
    """
    lum = luma(hdr, REC709)
    if stats is None:
        stats = display_stats(lum)
    scale = 0.18 / max(stats["log_avg"], 1e-12)
    l = np.minimum(lum * scale, 1e15)  # guard: l * l below overflows float32 past ~1e19 (NaN -> black)
    ld = l * (1 + l / stats["white"] ** 2) / (1 + l)
    ratio = np.where(lum > 1e-12, ld / np.maximum(lum, 1e-12), 0.0)
    out = np.clip(hdr * ratio[..., None], 0, 1)
    out = srgb_encode(out)
    return np.nan_to_num(np.clip(out, 0, 1)).astype(np.float32), stats


# -- layers and atlases: what the atlas export and ``layercam edit`` share -------------------------
def layer_weights(alpha: np.ndarray | None, n_layers: int, hw: tuple[int, int]) -> list[np.ndarray]:
    """How much each layer is seen per pixel: ``[1 - alpha, alpha]``, or ``[1]`` for one layer."""
    if alpha is None or n_layers == 1:
        return [np.ones(hw, np.float32)]
    return [1.0 - alpha, alpha]


def composite_layers(layer_r: list[np.ndarray], alpha: np.ndarray | None) -> np.ndarray:
    """Linear irradiance of the layers ``[L x (H, W, 3)]`` -> the frame's ``(H, W, 3)`` (as the scene
    composites: ``alpha * r_1 + (1 - alpha) * r_0``)."""
    if alpha is None or len(layer_r) == 1:
        return layer_r[0]
    a = alpha[..., None]
    return a * layer_r[1] + (1.0 - a) * layer_r[0]


def atlas_uv_grid(res: int, device="cpu") -> torch.Tensor:
    """The atlas image grid: ``res x res`` pixel centres over ``[-1, 1]^2`` as ``(res*res, 2)`` uv,
    row-major (row = v, column = u), the convention of ``grid_sample(align_corners=False)``."""
    return pixel_grid(res, res, device)


@torch.no_grad()
def sample_atlas(model, layer: int, res: int, chunk: int = 65536) -> np.ndarray:
    """Layer ``layer``'s atlas on :func:`atlas_uv_grid` -> ``(res, res, 3)`` log2 irradiance."""
    dev = next(model.parameters()).device
    uv = atlas_uv_grid(res, dev)
    atlas = model.scene.atlases[layer]
    out = [atlas(uv[s : s + chunk]).float().cpu() for s in range(0, uv.shape[0], chunk)]
    return torch.cat(out).view(res, res, 3).numpy()


def splat_coverage(uvs: list[np.ndarray], weights: list[np.ndarray], res: int, min_weight: float = 0.5) -> np.ndarray:
    """Where frames map to in an atlas: ``(res, res)`` float in [0, 1].

    ``uvs[i] (H, W, 2)`` and ``weights[i] (H, W)`` per frame (the layer's visibility); a pixel of the
    atlas is covered when the summed weight landing in it reaches ``min_weight``. Small gaps (atlas
    finer than the frames) are closed morphologically."""
    acc = np.zeros(res * res, np.float64)
    for uv, w in zip(uvs, weights):
        splat_add(acc, uv, w, res)
    return coverage_from_splat(acc, res, min_weight)


def splat_add(acc: np.ndarray, uv: np.ndarray, weight: np.ndarray, res: int) -> None:
    """Adds one frame's ``weight (H, W)`` at its atlas coordinates ``uv (H, W, 2)`` into ``acc (res*res,)``."""
    ij = np.floor((uv.reshape(-1, 2) + 1.0) * 0.5 * res).astype(np.int64)
    wt = weight.reshape(-1).astype(np.float64)
    ok = (ij >= 0).all(1) & (ij < res).all(1) & (wt > 1e-3)
    acc += np.bincount(ij[ok, 1] * res + ij[ok, 0], weights=wt[ok], minlength=res * res)


def coverage_from_splat(acc: np.ndarray, res: int, min_weight: float = 0.5) -> np.ndarray:
    """``acc`` of :func:`splat_add` -> coverage ``(res, res)`` in {0, 1}, small gaps closed."""
    import cv2

    cov = (acc.reshape(res, res) >= min_weight).astype(np.uint8)
    cov = cv2.morphologyEx(cov, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    return cov.astype(np.float32)


def checker_overlay(frame: np.ndarray, uv: np.ndarray, weight: np.ndarray, cells: int = 16) -> np.ndarray:
    """How a frame maps into an atlas: where ``weight (H, W)`` > 0.5 the frame ``(H, W, 3)`` is blended
    with a checkerboard of ``cells x cells`` squares over the atlas, coloured by ``(u, v)``; elsewhere
    the frame is darkened. Returns ``(H, W, 3)`` in [0, 1]."""
    u, v = uv[..., 0], uv[..., 1]
    parity = (np.floor((u + 1) * 0.5 * cells) + np.floor((v + 1) * 0.5 * cells)) % 2
    col = np.stack([np.clip((u + 1) / 2, 0, 1), np.clip((v + 1) / 2, 0, 1), np.full_like(u, 0.5)], -1)
    checker = col * (0.45 + 0.55 * parity[..., None])
    on = (weight > 0.5)[..., None]
    return np.clip(np.where(on, 0.45 * frame + 0.55 * checker, 0.35 * frame), 0, 1).astype(np.float32)


@torch.no_grad()
def tone_map_log2(model, log2_r: np.ndarray, log2_dt, chunk: int = 65536) -> np.ndarray:
    """Through the learned camera (no blur): ``log2_r (..., 3)`` at exposure ``log2_dt`` (a float or an
    array broadcastable to ``(..., 1)``) -> pixel values ``(..., 3)`` in [0, 1]; ``chunk`` pixels at a
    time (a tone mapper evaluated per pixel holds its width's activations for each)."""
    shp = log2_r.shape
    z = torch.as_tensor(np.asarray(log2_r, np.float32).reshape(-1, 3))
    dt = torch.as_tensor(np.broadcast_to(np.asarray(log2_dt, np.float32), shp[:-1] + (1,)).reshape(-1, 1).copy())
    dev = next(model.parameters()).device
    out = np.empty((z.shape[0], 3), np.float32)
    for s in range(0, z.shape[0], chunk):
        out[s : s + chunk] = model.tone_map(z[s : s + chunk].to(dev), dt[s : s + chunk].to(dev)).float().cpu().numpy()
    return out.reshape(shp)


@torch.no_grad()
def white_radiance(model, z_range: float = 24.0, knots: int = 4097) -> float:
    """Diffuse white of a run's linear HDR, where its HDR video puts BT.2408's reference white: the
    radiance an SDR camera at the run's reference exposure (``model.exposure.reference()``, the
    median of the frames' log2 exposures) records as signal 1.0. The learned camera at that
    exposure fixes the level of half signal (per channel, where its curve crosses 0.5; their mean
    in stops); half signal is taken as sRGB's 0.5, ``srgb_decode(0.5)`` = 21.4% of white, how 8-bit
    frames code light. With the fixed sRGB curve this is where it clips (``2^-reference``)."""
    from layercam.core.colour import srgb_decode

    z = torch.linspace(-z_range, z_range, knots)
    curve = model.tone.curve(z.to(next(model.parameters()).device)).float().cpu().numpy()  # (K, 3)
    zs = z.numpy()
    half = [np.interp(0.5, np.maximum.accumulate(curve[:, c]) + np.arange(knots) * 1e-9, zs) for c in range(3)]
    return float(2.0 ** (np.mean(half) - model.exposure.reference()) / srgb_decode(0.5))


@torch.no_grad()
def inverse_tone(model, rgb: np.ndarray, log2_dt: float, z_range: float = 24.0, knots: int = 4097) -> np.ndarray:
    """Invert the learned camera at one exposure: pixel values ``(..., 3)`` -> log2 irradiance that the
    tone mapper at ``log2_dt`` maps to them (per channel, by interpolating the monotone hull of the
    curve on ``knots`` points over ``+-z_range`` stops). Values the curve never reaches (past its
    clipping points, or beyond 1/255 and 254/255) are taken at the nearest reachable value."""
    z = torch.linspace(-z_range, z_range, knots)
    dev = next(model.parameters()).device
    curve = model.tone.curve(z.to(dev)).float().cpu().numpy()  # (K, 3)
    zs = z.numpy()
    rgb = np.asarray(rgb, np.float32)
    out = np.empty(rgb.shape, np.float32)
    for c in range(3):
        cv = np.maximum.accumulate(curve[:, c]) + np.arange(knots) * 1e-9  # strictly increasing
        lo, hi = max(cv[0], 1.0 / 255), min(cv[-1], 254.0 / 255)
        out[..., c] = np.interp(np.clip(rgb[..., c], lo, hi), cv, zs) - float(log2_dt)
    return out


# -- the clip again with new camera settings (layercam render) ---------------------------------------
def exposure_at(model, f: float) -> float:
    """log2 exposure at a fractional frame index (linear between neighbouring frames)."""
    v = model.exposure.values().detach().cpu().numpy().astype(np.float64)
    return float(np.interp(f, np.arange(len(v)), v))


def exposure_frames(model, meta: dict, ev: float, keep_blur: bool = False, chunk: int = 65536, z0: float | None = None):
    """Every frame at ``ev`` stops from the reference exposure (``z0``, default the model's):
    ``(T, H, W, 3)``."""
    hw = tuple(meta["frame_hw"])
    z = (model.exposure.reference() if z0 is None else z0) + ev
    return np.stack([render_frame(model, t, hw, "ldr", log2_dt=z, blur=keep_blur,
                                  chunk=chunk)["ldr"] for t in range(int(meta["n_frames"]))])


def exposure_sweep(model, meta: dict, evs, frame: int, keep_blur: bool = False, z0: float | None = None):
    """One view at each of ``evs`` (stops from the reference exposure, ``z0`` or the model's):
    ``(N, H, W, 3)``."""
    hw = tuple(meta["frame_hw"])
    z0 = model.exposure.reference() if z0 is None else z0
    return np.stack([render_frame(model, frame, hw, "ldr", log2_dt=z0 + float(e), blur=keep_blur)["ldr"] for e in evs])


def focus_sweep(model, meta: dict, fs, frame: int, ev: float | None = None, z0: float | None = None):
    """One view with the blur of each fractional image index in ``fs``: ``(N, H, W, 3)``; at the
    exposure interpolated at each ``f``, or at ``ev`` stops from the reference (``z0`` or the
    model's) when given."""
    hw = tuple(meta["frame_hw"])
    out = []
    for f in fs:
        z = exposure_at(model, float(f)) if ev is None else (model.exposure.reference() if z0 is None else z0) + ev
        out.append(render_frame(model, frame, hw, "ldr", log2_dt=z, t_blur=float(f), blur=True)["ldr"])
    return np.stack(out)
