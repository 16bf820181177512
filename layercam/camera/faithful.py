"""Faithful to the frame: the exported HDR of a frame agrees with what the frame saw.

The scene model averages every frame that sees a point (less noise than any one frame), fills in
what a frame clipped or crushed, and drops the camera's blur; but where it does not explain a
frame (a person it smeared, a ghost of another frame's content) the frame is right and the model
is not. Per pixel, the export adds to the model's sharp log irradiance ``w`` times the frame's
disagreement with the model, both read through the inverse of the learned camera at the frame's
exposure::

    log2 r = log2 r_model + w * (T^-1(c_frame) - T^-1(c_model))

where ``c_model`` is the model's rendering of the frame through its whole camera (blur included,
so the blur a sharp output drops is not put back). ``w`` is a Wiener weight of the disagreement
against the frame's noise, ``1 - kappa / rho`` clipped to [0, 1], with ``rho`` the local mean (a
Gaussian window) of the squared residual in units of the noise: about 1 where the model explains
the frame within its noise (then the model's average is kept), large where it does not (then the
frame is). It is multiplied per channel by how well the frame exposes the pixel (0 where the
channel is clipped or at the 8-bit floor: there the model fills in).

Where the frame did not see well (a channel clipped or at the floor) the neighbouring frames, which
another exposure may let see it, lend their corrections (:func:`neighbour_fill`): each neighbour's
``w * delta``, moved into this frame's view along the clip's optical flow where the flow is
consistent, enters with the weight the frame's own exposedness leaves, ``1 - exposedness``. In an
alternating-exposure video the long frames' clipped window is then corrected like the short frames
around it, instead of alternating between the model and the frames (flicker); and where a neighbour
saw a clipped channel, its evidence replaces the lower bound below (on the Basler clip the learned
curve's shoulder put a long frame's clipping point 0.6 stop above what the short frames around it
measured).

In a video from a static camera (``export.merge_neighbours``, auto) each frame's corrected
irradiance is then merged with its neighbours' at the same pixel (:func:`merge_neighbours`),
weighted as a bracket merge weighs its exposures (well-exposedness times exposure time), where they
reproduce what the frame recorded within its noise: on the Basler clip (alternating 3 EV) each
frame keeping its own noise and quantisation, short and long in turn, made the static background
flicker 3.2 codes (flow + Debevec 1.4); merged along the flow, 1.3; at the same pixel, 1.0. Where a
neighbour saw something else (the person moved) the frame's own measurement stays.

Clipped or at the floor (:func:`clip_bounds`): a channel at the 8-bit floor says only that the
irradiance is below what the camera maps to the first code value at the frame's exposure; a clipped
one, that it is above what it maps to the last. The export keeps the frame's log irradiance within
these bounds (the model, fitted to every frame, can stray past them where its fit is loose).
Where no frame of the clip saw a channel (:func:`unseen`: the model's irradiance is beyond the
clipping point of the clip's shortest exposure, or below the floor of its longest) nothing was
observed, and the export there is the model smoothed (``UNSEEN_SIGMA``): a smooth continuation, no
structure invented by the model's fit to nothing; black everywhere, it is kept below the longest
exposure's floor (clipped everywhere, the model's level is kept: the learned curve's shoulder, which
places the clipping level, is where it is least reliable).

Frames are ``(H, W, 3)`` float in [0, 1]; log irradiance ``(H, W, 3)``.
"""

from __future__ import annotations

import numpy as np

from layercam.core.visibility import CLIP_LEVEL, FLOOR_LEVEL

KAPPA = 2.0             # the disagreement must reach this many noise variances before the frame is trusted
WINDOW_SIGMA = 1.5      # px: the Gaussian window over which the disagreement is averaged
EXPOSED = (2.0 / 255, 12.0 / 255, 20.0 / 255, 2.5 / 255)  # well-exposedness ramps: 0 at the floor and within the
                        # last of these below the clipping level, 1 from the second / above the third below it
FLOOR = FLOOR_LEVEL     # a channel at or below this is at the floor; at or above its clipping level
                        # (visibility.clip_levels: CLIP_LEVEL, or lower where the camera clips lower), clipped
UNSEEN_SIGMA = 4.0      # px: the smoothing of the model where no frame saw the pixel
MERGE_KAPPA = 3.0       # a neighbour must reproduce the frame within this many noise deviations to be merged
NOISE_FLOOR = 2.0 / 255  # the noise the fidelity weight and the merge's agreement test assume at least (compression,
                        # quantisation: an mp4's measured noise is 0.3-1 code; docs/measurements.md)
NOISE_MARGIN = 2.0      # the clipping bounds are this many noise deviations loose
DENOISE_SIGMA = 1.0     # px: the Gaussian window of the export's adaptive Wiener filter (:func:`denoise_log2`)


def exposure_weight(frame: np.ndarray, levels: np.ndarray | None = None) -> np.ndarray:
    """``(H, W, 3)`` in [0, 1]: how well each channel of ``frame`` is exposed (smooth ramps from 0
    at the 8-bit floor and at the clipping ``levels (3,)`` (default
    :data:`layercam.core.visibility.CLIP_LEVEL`) to 1 in between,
    ``EXPOSED``)."""
    a, b, c, d = EXPOSED
    lv = np.full(3, CLIP_LEVEL, np.float32) if levels is None else np.asarray(levels, np.float32)
    f = np.asarray(frame, np.float32)
    lo = np.clip((f - a) / (b - a), 0.0, 1.0)
    hi = np.clip((lv - d - f) / (c - d), 0.0, 1.0)
    s = lambda x: x * x * (3 - 2 * x)  # noqa: E731 - smoothstep
    return (s(lo) * s(hi)).astype(np.float32)


def frame_noise(frame: np.ndarray, exposed: np.ndarray, floor: float = NOISE_FLOOR) -> np.ndarray:
    """Per channel ``(3,)``: the frame's own noise (:func:`layercam.core.visibility.noise_sigma` over its
    well-exposed pixels), not the model's residual, which a model that fits each frame's noise
    makes small; at least ``floor`` (``NOISE_FLOOR``: a compressed video's measured noise misses its
    compression error, and the frame's own measurement would then be kept for it, flickering)."""
    from layercam.core.visibility import noise_sigma

    return np.maximum(np.array([noise_sigma(frame[..., c], exposed[..., c] > 0.5)
                                for c in range(3)], np.float32), floor)


def disagreement(frame: np.ndarray, pred: np.ndarray, sigma: np.ndarray, exposed: np.ndarray,
                 window: float = WINDOW_SIGMA) -> np.ndarray:
    """``(H, W)``: the local mean (Gaussian window of ``window`` px, over the exposed pixels only)
    of the squared residual ``frame - pred`` in units of the noise ``sigma (3,)``, averaged over the
    channels: about 1 where the model explains the frame within its noise."""
    import cv2

    r2 = ((np.asarray(frame, np.float32) - np.asarray(pred, np.float32)) / sigma) ** 2
    w = np.asarray(exposed, np.float32)
    num = cv2.GaussianBlur((r2 * w).sum(-1), (0, 0), window)
    den = cv2.GaussianBlur(w.sum(-1), (0, 0), window)
    return num / np.maximum(den, 1e-3)


def fidelity_weight(frame: np.ndarray, pred: np.ndarray, kappa: float = KAPPA,
                    levels: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
    """``(H, W, 3)`` in [0, 1]: how much of the frame's disagreement with the model's rendering
    ``pred`` to keep (the module's docstring), and a summary ``{"noise", "mean_weight"}``;
    ``levels (3,)``: the clipping levels (:func:`layercam.core.visibility.clip_levels`)."""
    exposed = exposure_weight(frame, levels)
    measured = frame_noise(frame, exposed, 0.0)
    sigma = np.maximum(measured, NOISE_FLOOR)
    rho = disagreement(frame, pred, sigma, exposed)
    wiener = np.clip(1.0 - kappa / np.maximum(rho, 1e-6), 0.0, 1.0)
    w = wiener[..., None] * exposed
    return w.astype(np.float32), {"noise": [round(float(s), 5) for s in sigma],
                                  "mean_weight": round(float(w.mean()), 4), "sigma": sigma,
                                  "sigma_measured": measured}


def _levels(model, log2_dt: float, levels: np.ndarray, floor=FLOOR) -> tuple[np.ndarray, np.ndarray]:
    """Per channel ``(3,)``: the log2 irradiance the camera maps to ``floor`` (a value or ``(3,)``)
    and to the clipping ``levels (3,)`` at ``log2_dt``."""
    from layercam.scene.render import inverse_tone

    return (inverse_tone(model, np.broadcast_to(np.asarray(floor, np.float32), (1, 3)).copy(), log2_dt)[0],
            inverse_tone(model, np.asarray(levels, np.float32)[None], log2_dt)[0])


def clip_bounds(model, frame: np.ndarray, log2_dt: float, levels: np.ndarray,
                sigma: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(lower, upper)`` log2 irradiance ``(H, W, 3)`` that ``frame``'s clipped (at ``levels
    (3,)``) and floor channels imply at its exposure ``log2_dt`` (``-inf`` / ``inf`` elsewhere).
    With the frame's noise ``sigma (3,)`` the bounds are ``NOISE_MARGIN`` noise deviations looser: a
    dark pixel that noise pushed to 0 may have seen more than the floor; and a floor channel whose
    3x3 neighbourhood averages above the floor by more than that margin bounds nothing (noise took
    one pixel to 0: on NTIRE 000003 such red channels of the reference, at 0 amid 20-40 codes,
    came out as black specks 1.5 stops under their surround)."""
    import cv2

    margin = np.zeros(3, np.float32) if sigma is None else NOISE_MARGIN * np.asarray(sigma, np.float32)
    z_floor, z_clip = _levels(model, log2_dt, np.maximum(levels - margin, 0.5), FLOOR + margin)
    f = np.asarray(frame, np.float32)
    dark = cv2.blur(f, (3, 3), borderType=cv2.BORDER_REFLECT) <= FLOOR + margin
    upper = np.where((f <= FLOOR) & dark, z_floor, np.inf).astype(np.float32)
    lower = np.where(f >= levels, z_clip, -np.inf).astype(np.float32)
    return lower, upper


def unseen(model, z: np.ndarray, log2_dts, levels: np.ndarray,
           stack: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """````(above, below, bound)``: ``above``, ``below`` bool ``(H, W, 3)`` where the log2
    irradiance ``z`` is beyond the clipping
    point of the shortest of the exposures ``log2_dts`` or below the floor of the longest (no frame
    of the clip can have seen it), and ``bound (H, W, 3)``, what each side must keep to (the clip
    level of the shortest exposure above, the floor of the longest below). With ``stack (N, H, W,
    3)``, the clip's frames registered into this view (a static scene; or :func:`stack_extremes` of
    them, computed once), the test is on the data instead: clipped, or at the floor, in every frame
    (a model that fits its floors loosely can
    stay above the longest exposure's floor where every frame is black)."""
    lo_dt, hi_dt = float(np.min(log2_dts)), float(np.max(log2_dts))
    z_clip = _levels(model, lo_dt, levels)[1]
    z_floor = _levels(model, hi_dt, levels)[0]
    if stack is None:
        above, below = z >= z_clip, z <= z_floor
    else:
        above, below = stack if isinstance(stack, tuple) else stack_extremes(stack, levels)
    bound = np.where(above, z_clip, np.where(below, z_floor, 0.0)).astype(np.float32)
    return above, below, bound


def stack_extremes(stack, levels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(above, below)`` ``(H, W, 3)`` bool: where every frame of ``stack (N, H, W, 3)`` (read a
    frame at a time) is clipped (at ``levels``), and where every one is at the floor. What
    :func:`unseen` tests on a static scene; computed once, it may be passed as ``stack``."""
    above = below = None
    for f in stack:
        f = np.asarray(f)
        a, b = f >= levels, f <= FLOOR
        above, below = (a, b) if above is None else (above & a, below & b)
    return above, below


def smooth_within(z: np.ndarray, mask: np.ndarray, sigma: float = UNSEEN_SIGMA) -> np.ndarray:
    """``z (H, W, 3)`` smoothed by a Gaussian of ``sigma`` px over the pixels of ``mask (H, W, 3)``
    only, per channel (normalised convolution); unchanged outside ``mask``."""
    import cv2

    out = z.copy()
    for c in range(z.shape[-1]):
        m = mask[..., c].astype(np.float32)
        if not m.any():
            continue
        num = cv2.GaussianBlur(np.where(m > 0, z[..., c], 0.0).astype(np.float32), (0, 0), sigma)
        den = cv2.GaussianBlur(m, (0, 0), sigma)
        out[..., c] = np.where(m > 0, num / np.maximum(den, 1e-6), z[..., c])
    return out


def correction(model, frame: np.ndarray, t: int, levels: np.ndarray | None = None,
               chunk: int = 65536, kappa: float = KAPPA, geometry: bool = False) -> dict:
    """What ``frame (H, W, 3)`` (frame ``t``) says about the model: ``{"model_log2_r"}`` the
    model's log2 irradiance, ``"delta"`` the frame's disagreement with it through the inverse camera,
    ``"weight"`` the share of it to keep (:func:`fidelity_weight`), ``"exposed"``
    (:func:`exposure_weight`), all ``(H, W, 3)``; ``"log2_dts"`` the clip's exposures, ``"levels"``,
    ``"info"`` (with ``fit_map`` ``(H, W)``, the model through its camera against the frame: its
    squared error per pixel); with ``geometry`` also the frame's ``"uv"`` and ``"alpha"`` from the same render
    (:func:`~layercam.scene.render.render_frame`'s)."""
    import torch

    from layercam.scene.render import inverse_tone, render_frame

    geo = ("uv", "alpha") if geometry else ()
    out = render_frame(model, t, frame.shape[:2], ("log2_r", "ldr", *geo), blur=True, chunk=chunk)
    with torch.no_grad():
        dts = model.exposure.values().detach().float().cpu().numpy()
    log2_dt = float(dts[int(t)])
    levels = np.full(3, CLIP_LEVEL, np.float32) if levels is None else np.asarray(levels, np.float32)
    w, info = fidelity_weight(frame, out["ldr"], kappa, levels)
    # the model through its camera against the frame
    fit = ((np.clip(out["ldr"], 0.0, 1.0) - np.asarray(frame, np.float32)) ** 2).mean(-1)
    info["fit_map"] = fit
    delta = inverse_tone(model, frame, log2_dt) - inverse_tone(model, out["ldr"], log2_dt)
    return {"model_log2_r": out["log2_r"], "delta": delta, "weight": w,
            "exposed": exposure_weight(frame, levels), "log2_dts": dts, "levels": levels,
            "info": info,
            **{k: out[k] for k in geo}}


def merge_neighbours(own: tuple[np.ndarray, np.ndarray],
                     neighbours: list[tuple[np.ndarray, np.ndarray, np.ndarray]], frame: np.ndarray,
                     model, log2_dt: float, levels: np.ndarray, sigma: np.ndarray,
                     exposed: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Frame ``t``'s corrected log2 irradiance merged with its neighbours' where they agree with
    what frame ``t`` recorded, as a merge of a bracket weighs its exposures:
    ``sum a_n z_n / sum a_n`` over the frame (``own = (z_t, a_t)``) and ``neighbours`` (each
    ``(z_n, a_n, flow)`` in the neighbour's view, moved into this one along ``flow`` (NaN: it
    lends nothing there)), ``z`` the model corrected by that frame (:func:`correction`) and ``a``
    its weight, how well it exposed the pixel times its exposure time relative to the longest
    (``merge_weight``: photon noise, whose variance in log irradiance falls as the exposure
    grows). A neighbour counts only as far as it agrees with ``frame``: through the learned camera
    at ``log2_dt`` it must reproduce ``frame`` within ``MERGE_KAPPA`` times the frame's noise
    ``sigma (3,)`` (at least ``NOISE_FLOOR``), averaged in a ``WINDOW_SIGMA`` window over the
    channels the frame exposed well and, as bounds, those it clipped (the neighbour must be at least
    as bright) or left at the floor (at most as dark); where it has none of these nearby the
    neighbour cannot be checked and is not merged. ``exposed``: the frame's
    :func:`exposure_weight`, when known already. Without it each frame of an alternating-exposure
    video kept its own noise and quantisation, short and long frames in turn: flicker on a static
    background. Returns ``(z, weight)`` ``(H, W, 3)``: the merge and the summed weight (0 where no
    frame saw the pixel)."""
    import cv2

    from layercam.core.geometry import warp
    from layercam.scene.render import tone_map_log2

    z_t, a_t = own
    num, den = a_t * z_t, a_t.copy()
    f = np.asarray(frame, np.float32)
    good = (exposure_weight(f, levels) if exposed is None else exposed) > 0.5
    clipped, floor = f >= levels, f <= FLOOR
    counted = (good | clipped | floor).astype(np.float32)
    den_r = cv2.GaussianBlur(counted.sum(-1), (0, 0), WINDOW_SIGMA)  # how much of the window can be checked
    checkable = den_r > 0.5
    s = np.maximum(np.asarray(sigma, np.float32), NOISE_FLOOR)
    for z_n, a_n, fl in neighbours:
        ok = np.isfinite(fl).all(-1)
        move = np.where(ok[..., None], fl, 0.0).astype(np.float32)
        zw = warp(z_n, move)
        aw = warp(a_n, move) * ok[..., None]
        c = tone_map_log2(model, zw, log2_dt)  # the neighbour's irradiance as this frame would have recorded it
        r = np.where(good, c - f,
                     np.where(clipped, np.maximum(levels - c, 0.0),
                              np.where(floor, np.maximum(c - FLOOR, 0.0), 0.0)))
        rho = cv2.GaussianBlur(((r / s) ** 2 * counted).sum(-1), (0, 0), WINDOW_SIGMA) / np.maximum(den_r, 1e-3)
        agree = np.where(checkable, np.exp(-0.5 * rho / MERGE_KAPPA**2), 0.0)[..., None]
        num += aw * agree * zw
        den += aw * agree
    return np.where(den > 1e-6, num / np.maximum(den, 1e-6), z_t).astype(np.float32), den.astype(np.float32)


def noise_log2(model, frame: np.ndarray, log2_dt: float, sigma: np.ndarray, exposed: np.ndarray) -> np.ndarray:
    """``(H, W, 3)``: the variance that ``frame``'s own noise ``sigma (3,)`` (in pixel values, as
    measured: :func:`frame_noise` without the floor) puts
    into its log2 irradiance read through the inverse of the learned camera at ``log2_dt``:
    ``(sigma * dz/dc)^2``, the slope by a central difference; 0 where the frame does not expose the
    channel well (``exposed`` below 0.5: there the model or a neighbour stands in)."""
    from layercam.scene.render import inverse_tone

    f = np.asarray(frame, np.float32)
    h = 0.5 / 255
    lo, hi = np.clip(f - h, 0.0, 1.0), np.clip(f + h, 0.0, 1.0)
    slope = (inverse_tone(model, hi, log2_dt) - inverse_tone(model, lo, log2_dt)) / np.maximum(hi - lo, 1e-6)
    var = (np.asarray(sigma, np.float32) * slope) ** 2
    return np.where(np.asarray(exposed) >= 0.5, np.nan_to_num(var, nan=0.0, posinf=0.0), 0.0).astype(np.float32)


def denoise_log2(z: np.ndarray, var: np.ndarray, sigma: float = DENOISE_SIGMA) -> np.ndarray:
    """An adaptive Wiener filter (Lee's) on log irradiance ``z (H, W, 3)`` with the noise variance
    ``var (H, W, 3)`` per pixel: ``m + max(v - var, 0) / v * (z - m)``, ``m`` and ``v`` the local mean
    and variance (Gaussian window ``sigma`` px). Where the local variance is the noise's the local
    mean is kept; at an edge or texture well above the noise the pixel is; where ``var`` is 0, ``z``
    unchanged. The model fits each frame's noise where every atlas cell is seen by one pixel per
    frame (a 3-shot bracket), so its fused view is filtered so (docs/measurements.md)."""
    import cv2

    z = np.asarray(z, np.float32)
    out = z.copy()
    for c in range(z.shape[-1]):
        n = np.asarray(var[..., c], np.float32)
        if not (n > 0).any():
            continue
        x = z[..., c]
        m = cv2.GaussianBlur(x, (0, 0), sigma)
        v = np.maximum(cv2.GaussianBlur(x * x, (0, 0), sigma) - m * m, 1e-12)
        out[..., c] = np.where(n > 0, m + np.maximum(v - n, 0.0) / v * (x - m), x)
    return np.where(np.isfinite(out), out, z).astype(np.float32)


def merge_weight(exposed: np.ndarray, log2_dt: float, log2_dts) -> np.ndarray:
    """A frame's weight in :func:`merge_neighbours`: its well-exposedness ``(H, W, 3)`` times its
    exposure time relative to the clip's longest, ``2^(log2_dt - max log2_dts)``."""
    return (np.asarray(exposed, np.float32)
            * np.float32(2.0 ** (float(log2_dt) - float(np.max(log2_dts))))).astype(np.float32)


def neighbour_fill(neighbours: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray] | None:
    """The neighbours' corrections in this frame's view, ``sum w_n delta_n / max(sum w_n, 1)``
    over ``neighbours``, each ``(w delta, w, flow (H, W, 2))`` in the neighbour's view with the
    flow from this frame's pixels to the neighbour's (NaN where there is none: that neighbour lends
    nothing there), and how much they saw, ``min(sum w_n, 1)``: ``(fill, support)``, ``(H, W, 3)``
    each; None without neighbours."""
    from layercam.core.geometry import warp

    num = den = None
    for wd, w, fl in neighbours:
        ok = np.isfinite(fl).all(-1)
        f = np.where(ok[..., None], fl, 0.0).astype(np.float32)
        wn = warp(w, f) * ok[..., None]
        part = warp(wd, f) * ok[..., None]
        num = part if num is None else num + part
        den = wn if den is None else den + wn
    return None if num is None else ((num / np.maximum(den, 1.0)).astype(np.float32),
                                     np.minimum(den, 1.0).astype(np.float32))


def faithful_log2(model, frame: np.ndarray, t: int, levels: np.ndarray | None = None,
                  stack: np.ndarray | None = None, chunk: int = 65536, kappa: float = KAPPA,
                  corr: dict | None = None, fill: tuple[np.ndarray, np.ndarray] | None = None,
                  merge: list | None = None, clipped: str = "model", denoise: bool = False) -> dict:
    """Frame ``t``'s log2 irradiance ``(H, W, 3)``: the model's, corrected where it disagrees with
    ``frame (H, W, 3)`` beyond the frame's noise (:func:`correction`, or ``corr`` when computed
    already), where the frame did not see well by the neighbours' corrections ``fill`` (``(fill,
    support)``, :func:`neighbour_fill`), kept within the bounds of the frame's clipping (at the clip's
    ``levels (3,)``, :func:`layercam.core.visibility.clip_levels`; default
    :data:`layercam.core.visibility.CLIP_LEVEL`) and floor,
    smooth where no frame of the clip saw it (:func:`unseen`; ``stack``: the clip's frames
    registered into this view, for a static scene) (the module's docstring); ``merge``: the
    neighbours' ``(z_n, a_n, flow)`` to merge with where they agree (:func:`merge_neighbours`);
    ``clipped``: where every frame clipped, "model" keeps the model's level (smoothed), "clip" holds
    the irradiance at most at the clipping point of the shortest exposure (``export.clipped_everywhere``;
    what each gains and loses: docs/measurements.md); ``denoise``: an adaptive Wiener filter against
    the noise the frame's own measurement carries (:func:`denoise_log2`, ``export.denoise``). Returns
    ``{"log2_r", "model_log2_r", "weight", "unseen", "info"}``."""
    c = correction(model, frame, t, levels, chunk, kappa) if corr is None else corr
    out, w, dts, levels, info = {"log2_r": c["model_log2_r"]}, c["weight"], c["log2_dts"], c["levels"], dict(c["info"])
    log2_dt = float(dts[int(t)])
    z = out["log2_r"] + w * c["delta"]
    if fill is not None:
        z = z + (1.0 - c["exposed"]) * fill[0]
    if merge:  # the neighbours' measurements where they agree with this frame's (merge_neighbours)
        z, _ = merge_neighbours((z, merge_weight(c["exposed"], log2_dt, dts)), merge, frame, model,
                                log2_dt, levels, info["sigma"], c["exposed"])
    above, below, bound = unseen(model, out["log2_r"], dts, levels, stack)
    hidden = above | below
    z = np.where(hidden, smooth_within(out["log2_r"], hidden), z)
    if clipped not in ("model", "clip"):
        raise ValueError(f"unknown clipped-everywhere fill {clipped!r}")
    # black in every frame: darker than the longest exposure's floor; with "clip", clipped in every
    # frame: no brighter than the shortest exposure's clipping point (``bound`` holds both)
    z = np.where(below | (above & (clipped == "clip")), np.minimum(z, bound), z)
    sigma = info.pop("sigma")
    measured = info.pop("sigma_measured", sigma)  # a corr made by hand may carry only "sigma"
    if denoise:  # the noise as measured, without the Wiener weight's floor (which blurs a clean stack)
        z = denoise_log2(z, noise_log2(model, frame, log2_dt, measured, c["exposed"]))
    lower, upper = clip_bounds(model, frame, log2_dt, levels, sigma)
    if fill is not None:  # a neighbour that saw it says more than the learned curve's shoulder
        lower = np.where(fill[1] > 0.5, -np.inf, lower)
    z = np.clip(z, lower, upper).astype(np.float32)
    info["unseen_share"] = round(float(hidden.mean()), 4)
    info["merged"] = bool(merge)
    return {"log2_r": z, "model_log2_r": out["log2_r"], "weight": w, "unseen": hidden, "info": info}
