"""Step 5: each mask checked against the background its neighbours show (a clean plate).

Frames ``t +- 2, 4, .., 2 * REACH`` are warped into frame ``t`` by the chained camera homographies
(:func:`layercam.vision.segment.camera.border_homographies`), their object (its mask, dilated) left out,
each mapped onto frame ``t``'s levels by quantiles (another exposure reads the same), samples not
well exposed left out; the per-pixel median is the background behind the object. A limb the flow
was too coarse to see differs from it: within a ring of ``RING`` of the short side around the mask,
pixels whose residual (largest channel, smoothed 1 px) exceeds ``JOIN`` join the mask; mask pixels
that match it within ``LEAVE`` leave it (flow bleeding onto the wall beside the object) where at
least ``SURE`` neighbours show them whose object has moved off its place (registered, its mask overlaps
this frame's by IoU under ``APART``). Without neighbours a frame keeps its mask. After the colour
cut, :func:`texture_refine` drops mask pixels whose texture is the plate's, at any brightness (the
object's shadow).
"""

from __future__ import annotations

import numpy as np

from layercam.vision.segment.clean import clean_mask

JOIN = 0.15     # a pixel this far from the clean plate (pixel values) near the mask joins it
LEAVE = 0.075   # a mask pixel this close to it leaves
APART = 0.5     # a neighbour judges where its object overlaps this frame's by less than this IoU
SURE = 3        # a mask pixel matching the plate leaves where this many such neighbours show it
REACH = 4       # neighbours 2, 4, .. 2 * REACH frames away
RING = 0.05     # how far from the mask pixels may join, a share of the short side
REL_EPS = 0.03  # the relative residual's floor: near-black noise does not read as a large ratio


def _matched(src: np.ndarray, dst: np.ndarray, ok: np.ndarray, levels: int = 65, samples: int = 1 << 17) -> np.ndarray:
    """``src (H, W, 3)`` mapped per channel onto ``dst``'s levels by their quantiles over ``ok``: a
    monotone map, so a neighbour shot at another exposure (any camera curve) reads as ``dst`` would.
    Above ``samples`` pixels the quantiles come from an even subsample and the map is applied as a
    4096-entry table (a 1080p frame: 0.57 s -> 0.05 s per neighbour)."""
    qs = np.linspace(0, 100, levels)
    idx = np.flatnonzero(ok)
    if len(idx) > samples:
        idx = idx[:: -(-len(idx) // samples)]
    big = src.shape[0] * src.shape[1] > samples
    out = np.empty_like(src)
    for c in range(src.shape[-1]):
        a, b = np.percentile(src[..., c].ravel()[idx], qs), np.percentile(dst[..., c].ravel()[idx], qs)
        a = np.maximum.accumulate(a + np.arange(levels) * 1e-6)  # strictly increasing for interp
        if big:
            lut = np.interp(np.linspace(0, 1, 4096), a, b).astype(src.dtype)
            out[..., c] = lut[np.clip(np.rint(src[..., c] * 4095), 0, 4095).astype(np.int32)]
        else:
            out[..., c] = np.interp(src[..., c], a, b)
    return out


def _nan_median(stack: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Median over axis 0 of ``stack (K, H, W, C)`` whose missing samples are NaN in every channel,
    ``count (H, W)`` the samples present (NaN where none): ``np.nanmedian``'s values, by one sort."""
    srt = np.sort(stack, axis=0)  # NaN sort last
    lo = np.maximum((count - 1) // 2, 0)[None, ..., None]
    hi = np.maximum(count // 2, 0)[None, ..., None]
    lo, hi = np.broadcast_to(lo, (1,) + stack.shape[1:]), np.broadcast_to(hi, (1,) + stack.shape[1:])
    return 0.5 * (np.take_along_axis(srt, lo, 0)[0] + np.take_along_axis(srt, hi, 0)[0])


def background_refine(frames: np.ndarray, masks: np.ndarray,
                      homs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Masks ``(T, H, W)`` bool corrected by each frame's residual against the background its
    neighbours show (module docstring); ``homs (T-1, 3, 3)``: frame t -> t+1 pixels.

    Returns ``(masks, residual, plate)``: the residual is each frame's relative difference from that
    background, ``(T, H, W)`` float16, the largest channel of ``|log(bg + 0.03) - log(frame +
    0.03)|`` smoothed 1 px, 0 where no neighbour shows the background (what
    :func:`layercam.vision.segment.colour.colour_cut` gates on); the plate is that background,
    ``(T, H, W, 3)`` float16, NaN where no neighbour whose object moved off shows it (what
    :func:`texture_refine` reads)."""
    import cv2

    from layercam.core.geometry import chain_homographies
    from layercam.core.visibility import well_exposed

    m = np.asarray(masks) > 0.5
    fr = np.asarray(frames, np.float32)
    T, h, w = m.shape
    rel = np.zeros((T, h, w), np.float16)
    plate = np.full((T, h, w, 3), np.nan, np.float16)
    if T < 3:
        return m, rel, plate
    M = chain_homographies(np.asarray(homs, np.float64), T // 2)
    r = max(2, int(round(RING * min(h, w))))
    ko = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    kd = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
    objects = [cv2.dilate(x.astype(np.uint8), kd, iterations=2) for x in m]  # each frame's object, with a margin
    out = m.copy()
    for t in range(T):
        stack, fars = [], []
        for d in range(2, 2 * REACH + 1, 2):
            for s in (t - d, t + d):
                if not 0 <= s < T:
                    continue
                hm = np.linalg.inv(M[t]) @ M[s]
                ws = cv2.warpPerspective(fr[s], hm, (w, h), flags=cv2.INTER_LINEAR,
                                         borderMode=cv2.BORDER_CONSTANT, borderValue=(np.nan,) * 3)
                obj = cv2.warpPerspective(objects[s], hm, (w, h), flags=cv2.INTER_NEAREST, borderValue=1) > 0
                ms = cv2.warpPerspective(m[s].astype(np.uint8), hm, (w, h), flags=cv2.INTER_NEAREST) > 0
                union = np.count_nonzero(ms | m[t])
                far = union == 0 or np.count_nonzero(ms & m[t]) / union < APART  # the object moved off its place
                with np.errstate(invalid="ignore"):
                    bad = obj | ~well_exposed(ws)  # NaN outside the neighbour's view: not well exposed either
                ok = ~bad & ~m[t]
                if np.count_nonzero(ok) < 100:
                    continue
                ws = _matched(np.nan_to_num(ws, nan=0.0), fr[t], ok)
                ws[bad] = np.nan
                stack.append(ws)
                fars.append(far)
        if not stack:
            continue
        stack = np.stack(stack)
        fars = np.array(fars)
        present = ~np.isnan(stack[..., 0])
        count = present.sum(0)
        apart = present[fars].sum(0) if fars.any() else np.zeros_like(count)
        bg = _nan_median(stack, count)
        seen = (count > 0) & well_exposed(fr[t])
        res = np.where(seen, np.abs(np.nan_to_num(bg) - fr[t]).max(-1), 0.0).astype(np.float32)
        res = cv2.GaussianBlur(res, (0, 0), 1.0)
        ring = cv2.dilate(m[t].astype(np.uint8), ko) > 0
        sure = seen & (apart >= SURE)
        plate[t] = np.where((seen & (apart > 0))[..., None], bg, np.nan)
        drop = sure & (res < LEAVE)
        out[t] = clean_mask((m[t] & ~drop) | (ring & (res > JOIN)))
        lr = np.abs(np.log(np.nan_to_num(bg) + REL_EPS) - np.log(np.maximum(fr[t], 0) + REL_EPS)).max(-1)
        rel[t] = cv2.GaussianBlur(np.where(seen, lr, 0.0).astype(np.float32), (0, 0), 1.0)
    return out, rel, plate


TEXTURE_NCC = 0.7     # a mask pixel whose texture correlates this well with the plate's is background
                      # (fitted on DAVIS's training split: 0.7-0.8 alike)
TEXTURE_SIGMA = 1.0   # the correlation's Gaussian window, px


def texture_refine(frames: np.ndarray, masks: np.ndarray, plate: np.ndarray) -> np.ndarray:
    """Masks ``(T, H, W)`` bool without the pixels that show the clean plate's texture: where the
    normalised cross-correlation of the frame's grey levels with the plate's (``plate (T, H, W, 3)``
    of :func:`background_refine`, NaN where it is not known) over a Gaussian window of
    ``TEXTURE_SIGMA`` px is at least ``TEXTURE_NCC``. The correlation is blind to gain and offset,
    so the background under the object's shadow, or lit otherwise, still reads as the background
    (texture-based shadow detection: Jacques, Jung and Musse 2005; Sanin et al. 2012). Then
    :func:`layercam.vision.segment.clean.clean_mask` at half its radii; a frame left empty keeps its mask."""
    import cv2

    def blur(x):
        return cv2.GaussianBlur(x, (0, 0), TEXTURE_SIGMA)

    m = np.asarray(masks) > 0.5
    out = m.copy()
    for t in range(len(m)):
        p = np.asarray(plate[t], np.float32)
        known = ~np.isnan(p[..., 0])
        if not (m[t] & known).any():
            continue
        a, b = np.asarray(frames[t], np.float32).mean(-1), np.nan_to_num(p, nan=0.0).mean(-1)
        ma, mb = blur(a), blur(b)
        cov = blur(a * b) - ma * mb
        var = (blur(a * a) - ma * ma) * (blur(b * b) - mb * mb)
        same = known & (cov >= TEXTURE_NCC * np.sqrt(np.maximum(var, 1e-12)))
        kept = clean_mask(m[t] & ~same, scale=0.5)
        out[t] = kept if kept.any() else m[t]
    return out
