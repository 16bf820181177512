"""Motion segmentation without a detector: foreground masks from the cached optical flow.

A pixel is foreground when its flow disagrees with the per-frame global (camera) homography
fitted by RANSAC (:func:`layercam.flow.global_homographies`). Per frame the evidence is the
*smaller* of the forward residual (flow to the next frame) and the backward residual (flow to the
previous frame): a moving object disagrees in both directions, while the background it is about
to cover (leading edge, forward flow ill-defined) or has just uncovered (trailing edge, backward
flow ill-defined) disagrees in one only. The evidence is thresholded against the frame's own
residual noise, averaged with its neighbours along the flow (temporal consistency), rid of
parts that lie mostly where the frame has no texture the flow can follow (:func:`layercam.visibility.textured`:
flow over a smooth sky is interpolated, not measured), cleaned with
morphology (open, close, fill holes, drop small components), and frames where the object stands
still (no evidence) inherit their neighbours' masks along the flow. :func:`foreground_bootstrap`
then tightens each mask to the object's colour edges with GrabCut (flow masks overshoot by about a
DIS patch), checks it against the background its neighbours show (:func:`background_refine`) and
grows it to the object's colours learned over the whole clip, where the frame differs from that
background (:func:`colour_cut`: the flow often finds only part of the object). The masks' measured IoU with the true ones: ``docs/measurements.md``. Every threshold
is a setting (``segment`` section of :mod:`layercam.config`).

:func:`foreground_mappings` turns the masks into the foreground layer's bootstrap mapping: the
object's own motion (a similarity per frame pair fitted to the flow inside the mask, chained to
a reference frame), scaled so that the object fills the foreground atlas.

Shapes: flows ``(T-1, H, W, 2)`` in pixels (``layercam.flow`` conventions), masks ``(T, H, W)``.
"""

from __future__ import annotations

import numpy as np

from layercam.config import SegmentConfig
from layercam.errors import LayercamError

__all__ = ["SegmentConfig", "motion_masks", "clean_mask", "object_motion", "foreground_mappings", "background_refine", "colour_cut"]


def _check_flows(fw, bw) -> tuple[np.ndarray, np.ndarray]:
    f = np.asarray(fw, dtype=np.float32)
    b = np.asarray(bw, dtype=np.float32)
    if f.ndim != 4 or f.shape[-1] != 2 or b.shape != f.shape:
        raise LayercamError(f"motion segmentation needs forward and backward flows (T-1,H,W,2), got {f.shape} and {b.shape}")
    if f.shape[0] < 1:
        raise LayercamError("motion segmentation needs at least two frames")
    return f, b


def _flow_checks(f: np.ndarray, b: np.ndarray, fw_ok=None, bw_ok=None) -> tuple[np.ndarray, np.ndarray]:
    """The flows' forward-backward checks ``(T-1, H, W)`` bool: the given ones, else computed."""
    from layercam.flow import flow_consistency

    fo = flow_consistency(f, b) if fw_ok is None else np.asarray(fw_ok, bool)
    bo = flow_consistency(b, f) if bw_ok is None else np.asarray(bw_ok, bool)
    return fo, bo


def _warp_to(mask_next: np.ndarray, flow_t: np.ndarray) -> np.ndarray:
    from layercam.flow import warp

    return warp(mask_next.astype(np.float32), flow_t, border="constant")


def _temporal_vote(ev: np.ndarray, fw: np.ndarray, bw: np.ndarray, window: int) -> np.ndarray:
    """Average of each frame's evidence with its neighbours' (up to ``window`` each side), brought
    into its view along the chained flow. ``(T, H, W)`` float in [0, 1]."""
    T = ev.shape[0]
    acc = ev.astype(np.float32).copy()
    cnt = np.ones(T, np.float32)
    for t in range(T):
        for k in range(1, window + 1):
            if t + k >= T:
                break
            # bring frame t+k's evidence to frame t+k-1, ..., t
            m = ev[t + k].astype(np.float32)
            for j in range(t + k - 1, t - 1, -1):
                m = _warp_to(m, fw[j])
            acc[t] += m
            cnt[t] += 1
        for k in range(1, window + 1):
            if t - k < 0:
                break
            m = ev[t - k].astype(np.float32)
            for j in range(t - k, t):
                m = _warp_to(m, bw[j])
            acc[t] += m
            cnt[t] += 1
    return acc / cnt[:, None, None]


_PART_LLR = 1.0  # clean_mask: a part this far above the background's colours (log-likelihood ratio) is the object's
                 # (DAVIS libby at 282x158, bootstrap IoU with the colour cut's parts: 0.5 -> 0.540, 1.0 -> 0.554, 1.5 -> 0.546)
_THIN_LLR = 3.0  # clean_mask: a thin part the opening took comes back at this ratio (docs/layers/parts/: libby
                 # 0.562 -> 0.572 at 3, 0.579 at 2 and 1.5 but car 0.804 / 0.802)


def _part_means(lab: np.ndarray, n: int, values: np.ndarray) -> np.ndarray:
    """Mean of ``values (H, W)`` over each of the ``n`` labels of ``lab`` (0 included) ``(n,)``."""
    return np.bincount(lab.ravel(), weights=np.asarray(values, np.float64).ravel(), minlength=n) / np.maximum(np.bincount(lab.ravel(), minlength=n), 1)


def clean_mask(mask: np.ndarray, cfg: SegmentConfig | None = None, colour: np.ndarray | None = None, reach: float = 0.0, scale: float = 1.0) -> np.ndarray:
    """Morphology on one ``(H, W)`` bool mask: open, close, fill holes, drop small components, and
    keep one object: the largest component and those within ``cfg.gap`` times its size (the square
    root of its area) of it (parts an occluder splits off; DAVIS parkour's other blobs are sky and
    railings: bootstrap IoU 0.65 -> 0.70). With ``colour`` (``(H, W)``, the object : background
    colour log-likelihood ratio of :func:`colour_cut`), a component farther than that is kept too
    when its mean ratio is at least ``_PART_LLR`` (the object's colours) and it lies within
    ``reach`` pixels of the largest: a small dog that a trunk cuts in two keeps both halves; and
    what the opening took comes back where its ratio is at least ``_THIN_LLR`` and it touches what
    the opening left (a small dog's legs and tail are thinner than the opening). ``scale``: the
    radii of the opening (1% of the short side) and the closing (2%) times this (0: neither)."""
    import cv2
    from scipy import ndimage

    cfg = cfg or SegmentConfig()
    h, w = mask.shape
    m = mask.astype(np.uint8)
    r = max(1, int(round(0.01 * min(h, w))))
    ro, rc = int(round(scale * r)), int(round(scale * 2 * r))
    if ro > 0:
        m = cv2.morphologyEx(m, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * ro + 1, 2 * ro + 1)))
    if colour is not None:  # thin parts of the object's colours (legs, a tail) the opening took: back where they touch the rest
        thin = (mask.astype(bool) & (m == 0) & (np.asarray(colour) >= _THIN_LLR)).astype(np.uint8)
        nt, lt = cv2.connectedComponents(m | thin, connectivity=8)
        m = (_part_means(lt, nt, m) > 0)[lt].astype(np.uint8)  # the parts of mask + thin that hold some of the mask
    if rc > 0:
        m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * rc + 1, 2 * rc + 1)))
    # fill holes: background is what the border reaches
    pad = np.pad(m, 1)
    flood = pad.copy()
    ff = np.zeros((h + 4, w + 4), np.uint8)
    cv2.floodFill(flood, ff, (0, 0), 1)
    holes = (flood[1:-1, 1:-1] == 0)
    m = (m.astype(bool) | holes).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    if n <= 1:
        return np.zeros((h, w), bool)
    areas = stats[1:, cv2.CC_STAT_AREA]
    keep = (areas >= cfg.min_area * h * w) & (areas >= cfg.keep_fraction * areas.max())
    if keep.sum() > 1:
        main = 1 + int(np.argmax(areas))
        dist = cv2.distanceTransform((lab != main).astype(np.uint8), cv2.DIST_L2, 3)
        gaps = ndimage.minimum(dist, lab, np.arange(1, n))
        near = gaps <= cfg.gap * np.sqrt(areas.max())
        if colour is not None:
            near |= (gaps <= reach) & (_part_means(lab, n, colour)[1:] >= _PART_LLR)
        keep &= near
    return np.isin(lab, 1 + np.flatnonzero(keep))


def _fill_still_frames(masks: np.ndarray, fw: np.ndarray, bw: np.ndarray, frac: float) -> tuple[np.ndarray, list[int]]:
    """Frames with (almost) no mask inherit the nearest good neighbour's, carried along the flow."""
    T = masks.shape[0]
    area = masks.reshape(T, -1).sum(1)
    ref = float(np.median(area[area > 0])) if (area > 0).any() else 0.0
    if ref <= 0:
        return masks, []
    good = area >= frac * ref
    out = masks.copy()
    filled = []
    for t in np.flatnonzero(~good):
        cand = [(abs(s - t), s) for s in np.flatnonzero(good)]
        if not cand:
            break
        _, s = min(cand)
        m = masks[s].astype(np.float32)
        if s > t:
            for j in range(s - 1, t - 1, -1):
                m = _warp_to(m, fw[j])
        else:
            for j in range(s, t):
                m = _warp_to(m, bw[j])
        out[t] = m > 0.5
        filled.append(int(t))
    return out, filled


def _voted_masks(soft: np.ndarray, f: np.ndarray, b: np.ndarray, cfg: SegmentConfig, tex: np.ndarray | None = None) -> np.ndarray:
    """Soft evidence ``(T, H, W)`` -> cleaned masks ``(T, H, W)`` bool: thresholded at
    ``cfg.evidence``, averaged with its neighbours along the flow, thresholded at ``cfg.vote``;
    with ``tex`` (:func:`layercam.visibility.textured`), each connected part less than ``cfg.texture_share`` of which
    has texture is dropped before one object is kept."""
    import cv2

    ev = soft >= cfg.evidence
    vote = _temporal_vote(ev, f, b, cfg.window) if cfg.window > 0 else ev.astype(np.float32)
    out = []
    for t, v in enumerate(vote):
        m = v >= cfg.vote
        if tex is not None and m.any():
            n, lab = cv2.connectedComponents(m.astype(np.uint8), connectivity=8)
            m = m & (_part_means(lab, n, tex[t]) >= cfg.texture_share)[lab]
        out.append(clean_mask(m, cfg))
    return np.stack(out)


def motion_offsets(reach: int) -> tuple[int, ...]:
    """Frame offsets 1, 2, 4, ... up to ``reach`` (at least 1)."""
    return tuple(2**i for i in range(int(np.log2(max(int(reach), 1))) + 1))


def motion_masks(fw, bw, fw_ok=None, bw_ok=None, cfg: SegmentConfig | None = None, frames=None) -> tuple[np.ndarray, dict]:
    """Foreground masks of whatever moves on its own: ``(T, H, W)`` float32 in {0, 1}, and an info
    dict (coverage per frame, frames filled from neighbours, the static scene's model). ``fw_ok``,
    ``bw_ok`` ``(T-1, H, W)``: the flows' forward-backward checks (computed when None). With the
    ``frames`` ``(T, H, W[, C])``, a part of a frame's evidence that lies mostly where the frame has
    no texture (:func:`layercam.visibility.textured`) is not an object."""
    from layercam.motion import long_range_evidence
    from layercam.visibility import textured

    cfg = cfg or SegmentConfig()
    f, b = _check_flows(fw, bw)
    fo, bo = _flow_checks(f, b, fw_ok, bw_ok)
    soft, share = long_range_evidence(f, b, fo, bo, motion_offsets(cfg.reach), cfg.abs_px, cfg.k_sigma, cfg.f_vote)
    tex = smooth = None
    if frames is not None and cfg.texture > 0:
        tex = textured(frames, cfg.texture, cfg.texture_window)
        if tex.shape != soft["homography"].shape:
            raise LayercamError(f"motion segmentation: frames {tex.shape} do not match the flows {soft['homography'].shape}")
        smooth = float(1 - tex.mean())
    masks = _voted_masks(soft["homography"], f, b, cfg, tex)
    model = {"model": "homography", "epipolar_votes": round(share, 3)}
    if smooth is not None:
        model["untextured"] = round(smooth, 4)
    if soft["epipolar"] is not None:  # parallax: unless the epipolar model explained the object away too
        alt = _voted_masks(soft["epipolar"], f, b, cfg, tex)
        left = float(np.median(alt.reshape(len(alt), -1).mean(1)))
        model["epipolar_coverage"] = round(left, 4)
        if left >= cfg.min_object:
            masks, model["model"] = alt, "epipolar"
    masks, filled = _fill_still_frames(masks, f, b, cfg.still_fraction)
    masks = np.stack([clean_mask(m, cfg) for m in masks]) if filled else masks
    cover = masks.reshape(len(masks), -1).mean(1)
    info = {**model, "coverage_mean": float(cover.mean()), "coverage_min": float(cover.min()), "coverage_max": float(cover.max()), "filled_from_neighbours": filled, "empty_frames": int((cover == 0).sum())}
    return masks.astype(np.float32), info


# --------------------------------------------------------------------------------------------
# The foreground layer's bootstrap mapping
# --------------------------------------------------------------------------------------------


def object_motion(fw, masks, fw_ok=None, min_points: int = 12, seed: int = 0) -> np.ndarray:
    """Per pair ``(T-1, 3, 3)``: a similarity (rotation, scale, shift; RANSAC) mapping frame t's
    object pixels to frame t+1, fitted to the flow inside ``masks[t]``. Pairs with too few object
    pixels fall back to the median flow inside the mask, or to the identity. Where the fit moves the
    mask's centroid far from where the next mask's centroid is (the flow lost the object), the
    pair's motion is the centroid shift instead."""
    import cv2

    n, h, w = np.shape(fw)[:3]  # flows and masks read a pair at a time (they may be on disk)
    out = np.repeat(np.eye(3)[None], n, 0)
    cv2.setRNGSeed(seed)
    step = max(1, int(np.sqrt(h * w / 4000)))
    nxt = np.asarray(masks[0]) if n else None
    for i in range(n):
        cur, nxt = nxt, np.asarray(masks[i + 1])
        sel = cur > 0.5
        if fw_ok is not None:
            ok = sel & np.asarray(fw_ok[i], bool)
            sel = ok if ok.sum() >= min_points else sel
        ys, xs = np.nonzero(sel[::step, ::step])
        ys, xs = ys * step, xs * step
        if len(xs) < 3:
            continue
        d = np.asarray(fw[i], np.float32)[ys, xs]
        a = None
        if len(xs) >= min_points:
            src = np.stack([xs, ys], -1).astype(np.float32)
            a, _ = cv2.estimateAffinePartial2D(src, src + d, method=cv2.RANSAC, ransacReprojThreshold=1.0, maxIters=2000, confidence=0.995)
        if a is None or not np.all(np.isfinite(a)):
            out[i][:2, 2] = np.median(d, axis=0)
        else:
            out[i][:2] = a
        if cur.sum() >= min_points and (nxt > 0.5).sum() >= min_points:
            y0, x0 = np.nonzero(cur > 0.5)
            y1, x1 = np.nonzero(nxt > 0.5)
            c0, c1 = np.array([x0.mean(), y0.mean()]), np.array([x1.mean(), y1.mean()])
            pred = out[i][:2, :2] @ c0 + out[i][:2, 2]
            if np.linalg.norm(pred - c1) > max(1.5, 0.15 * np.sqrt(len(x0))):
                out[i] = np.eye(3)
                out[i][:2, 2] = c1 - c0
    return out


MAX_MAPPED_POINTS = 1 << 23  # foreground_mappings: mask pixels mapped into the atlas for its extent (every k-th beyond)


def foreground_mappings(h: int, w: int, masks: np.ndarray, fw=None, fw_ok=None, margin: float = 0.6, how: str = "object") -> tuple[np.ndarray, str]:
    """The foreground layer's ``h0`` ``(T, 3, 3)``: normalised frame coordinates -> atlas uv.

    how "object": the object's own chained motion (:func:`object_motion`) to the frame where the
    mask is largest, scaled isotropically so that the union of the mapped masks fills
    ``[-margin, margin]^2`` (the rest of the atlas is slack for what the masks missed).
    how "identity": every frame maps the same way (the paper's start), whole frame in the atlas.
    """
    from layercam.geometry import atlas_mappings, chain_homographies, fit_into_atlas

    T = masks.shape[0]
    if how == "identity" or fw is None or T < 2:
        return atlas_mappings(h, w, np.stack([np.eye(3)] * T)), "identity"
    area = np.array([np.count_nonzero(np.asarray(masks[t]) > 0.5) for t in range(T)])  # a frame at a time (masks may be on disk)
    if area.sum() == 0:
        return atlas_mappings(h, w, np.stack([np.eye(3)] * T)), "identity"
    if how != "object":
        raise LayercamError(f"unknown foreground bootstrap {how!r} (object | identity)")
    ref = int(np.argmax(area))
    pix = chain_homographies(object_motion(fw, masks, fw_ok), ref)
    pts = []
    every = max(1, -(-int(area.sum()) // MAX_MAPPED_POINTS))  # the percentiles from at most this many points
    for t in range(T):
        ys, xs = np.nonzero(np.asarray(masks[t]) > 0.5)
        ys, xs = ys[::every], xs[::every]
        if len(xs) == 0:
            continue
        p = pix[t] @ np.stack([xs + 0.5, ys + 0.5, np.ones_like(xs, dtype=np.float64)])
        pts.append((p[:2] / p[2:]).T)
    pts = np.concatenate(pts)
    lo, hi = np.percentile(pts, 1, axis=0), np.percentile(pts, 99, axis=0)
    return fit_into_atlas(pix, (lo + hi) / 2, max((hi - lo).max() / 2, 2.0), margin, h, w), f"object motion chained to frame {ref}"


def grabcut_refine(frame: np.ndarray, mask: np.ndarray, iters: int = 4) -> np.ndarray:
    """Tighten a motion mask ``(H, W)`` to the object's colour edges with GrabCut, seeded by the
    mask: eroded mask = sure foreground, mask = probable foreground, a ring around it = probable
    background, the rest = background. Flow-based masks overshoot the object by about a flow patch;
    this pulls them back. Returns ``(H, W)`` bool (the input when GrabCut cannot run)."""
    import cv2

    m = np.asarray(mask) > 0.5
    h, w = m.shape
    if m.sum() < 16 or m.all():
        return m
    u8 = np.ascontiguousarray((np.clip(frame, 0, 1) * 255).astype(np.uint8)[..., ::-1])
    r = max(2, int(round(0.03 * min(h, w))))
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    mm = m.astype(np.uint8)
    lab = np.full((h, w), cv2.GC_BGD, np.uint8)
    lab[cv2.dilate(mm, k, iterations=2) > 0] = cv2.GC_PR_BGD
    lab[m] = cv2.GC_PR_FGD
    lab[cv2.erode(mm, k, iterations=2) > 0] = cv2.GC_FGD
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    try:
        cv2.grabCut(u8, lab, None, bgd, fgd, iters, cv2.GC_INIT_WITH_MASK)
    except cv2.error:
        return m
    out = (lab == cv2.GC_FGD) | (lab == cv2.GC_PR_FGD)
    return out if out.any() else m


def refine_masks(frames: np.ndarray, background: np.ndarray, alpha: np.ndarray, threshold: float = 0.1) -> np.ndarray:
    """Foreground masks from a first fit of the two-layer model (``segment.refine``): where the frame
    differs from its background layer seen through the camera, near the fitted alpha.

    ``frames``, ``background`` ``(T, H, W, 3)`` pixel values in [0, 1] (the frames and the background
    layer through the learned camera at one exposure), ``alpha`` ``(T, H, W)``. The background
    atlas holds what every frame saw of the background, so a leg the motion masks missed differs from
    it and the wall they took in does not (the residual's largest channel, smoothed 1 px). Per
    frame: alpha > 0.5 eroded by 2% of the short side is kept (an object's inside can match a
    background the object always hid); the ring out to 5% of the short side around it is
    foreground where the residual exceeds ``threshold``; nothing farther (the near background's
    parallax differs from the atlas too); then :func:`clean_mask`. Returns ``(T, H, W)`` bool.
    DAVIS at 282x158 (fast; alpha IoU against the true masks): parkour 0.70 -> 0.75 after the
    second fit, docs/measurements.md."""
    import cv2

    T, h, w = alpha.shape
    ri = max(1, int(round(0.02 * min(h, w))))
    ro = max(ri + 1, int(round(0.05 * min(h, w))))
    ki = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * ri + 1, 2 * ri + 1))
    ko = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * ro + 1, 2 * ro + 1))
    out = np.zeros((T, h, w), bool)
    for t in range(T):
        res = np.abs(np.asarray(background[t], np.float32) - np.asarray(frames[t], np.float32)).max(-1)
        res = cv2.GaussianBlur(res, (0, 0), 1.0)
        a = (np.asarray(alpha[t]) > 0.5).astype(np.uint8)
        inner = cv2.erode(a, ki) > 0
        ring = cv2.dilate(a, ko) > 0
        out[t] = clean_mask(inner | (ring & (res > threshold)))
    return out


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


_REL_EPS = 0.03  # the relative residual's floor: near-black noise does not read as a large ratio


def _shifted_residual(bg: np.ndarray, frame: np.ndarray, shift: int) -> np.ndarray:
    """``(H, W)``: the largest channel of ``|bg - frame|``, the smallest over ``bg`` shifted by up
    to ``shift`` pixels (the offsets within a disc; edges repeated): static structure the global
    homography misregisters by its parallax matches (DAVIS parkour's wall: bootstrap IoU 0.800 ->
    0.822 at 1 px of 282x158; 3 px cost libby 0.13: its dark dog matches the dark grass)."""
    best = np.abs(bg - frame).max(-1)
    if shift <= 0:
        return best
    h, w = frame.shape[:2]
    pad = np.pad(bg, ((shift, shift), (shift, shift), (0, 0)), mode="edge")
    for dy in range(-shift, shift + 1):
        for dx in range(-shift, shift + 1):
            if (dx or dy) and dx * dx + dy * dy <= shift * shift:
                np.minimum(best, np.abs(pad[shift + dy : shift + dy + h, shift + dx : shift + dx + w] - frame).max(-1), out=best)
    return best


def background_refine(frames: np.ndarray, masks: np.ndarray, homs: np.ndarray, cfg: SegmentConfig | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Masks ``(T, H, W)`` bool corrected by each frame's residual against the background its neighbours
    show (``segment.background``): frames ``t +- 2, 4, .., 2 * background_reach`` warped into frame
    ``t`` by the chained global homographies (``homs (T-1, 3, 3)``, frame t -> t+1 pixels), their
    object (its mask, dilated) left out, each mapped onto frame ``t``'s levels by quantiles (another
    exposure reads the same), samples not well exposed (:func:`layercam.visibility.well_exposed`)
    left out; the per-pixel median is the
    background behind the object. A limb the flow was too coarse to see differs from it: within a
    ring of ``background_ring`` of the short side around the mask, pixels whose residual (largest
    channel, smoothed 1 px) exceeds ``background`` join the mask; mask pixels that match it within
    ``background_keep`` leave it (flow bleeding onto the wall beside the object) where at least 3
    neighbours show them whose object has moved off its place (registered, its mask overlaps this
    frame's by IoU under ``background_apart``: a slow object's neighbours still hold the legs
    their masks missed, and the median would match them). Then :func:`clean_mask`. Without
    neighbours a frame keeps its mask. DAVIS at 282x158 (bootstrap IoU; docs/layers/background/):
    car 0.760 -> 0.767, cows 0.727 -> 0.724, libby 0.387 -> 0.396, parkour 0.720 -> 0.766.

    Returns ``(masks, residual)``: the residual is each frame's relative difference from that
    background, ``(T, H, W)`` float16, the largest channel of ``|log(bg + 0.03) - log(frame +
    0.03)|`` smoothed 1 px, 0 where no neighbour shows the background (what :func:`colour_cut`
    gates on)."""
    import cv2

    from layercam.geometry import chain_homographies
    from layercam.visibility import well_exposed

    cfg = cfg or SegmentConfig()
    m = np.asarray(masks) > 0.5
    fr = np.asarray(frames, np.float32)
    T, h, w = m.shape
    rel = np.zeros((T, h, w), np.float16)
    if T < 3:
        return m, rel
    M = chain_homographies(np.asarray(homs, np.float64), T // 2)
    r = max(2, int(round(cfg.background_ring * min(h, w))))
    ko = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    kd = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
    objects = [cv2.dilate(x.astype(np.uint8), kd, iterations=2) for x in m]  # each frame's object, with a margin
    shift = int(round(cfg.background_shift * min(h, w)))
    out = m.copy()
    for t in range(T):
        stack, fars = [], []
        for d in range(2, 2 * cfg.background_reach + 1, 2):
            for s in (t - d, t + d):
                if not 0 <= s < T:
                    continue
                hm = np.linalg.inv(M[t]) @ M[s]
                ws = cv2.warpPerspective(fr[s], hm, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=(np.nan,) * 3)
                obj = cv2.warpPerspective(objects[s], hm, (w, h), flags=cv2.INTER_NEAREST, borderValue=1) > 0
                ms = cv2.warpPerspective(m[s].astype(np.uint8), hm, (w, h), flags=cv2.INTER_NEAREST) > 0
                union = np.count_nonzero(ms | m[t])
                far = union == 0 or np.count_nonzero(ms & m[t]) / union < cfg.background_apart  # the object moved off its place
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
        res = np.where(seen, _shifted_residual(np.nan_to_num(bg), fr[t], shift), 0.0).astype(np.float32)
        res = cv2.GaussianBlur(res, (0, 0), 1.0)
        ring = cv2.dilate(m[t].astype(np.uint8), ko) > 0
        drop = seen & (apart >= 3) & (res < cfg.background_keep)
        out[t] = clean_mask((m[t] & ~drop) | (ring & (res > cfg.background)), cfg)
        lr = np.abs(np.log(np.nan_to_num(bg) + _REL_EPS) - np.log(np.maximum(fr[t], 0) + _REL_EPS)).max(-1)
        rel[t] = cv2.GaussianBlur(np.where(seen, lr, 0.0).astype(np.float32), (0, 0), 1.0)
    return out, rel


def _graph_cut(unary: np.ndarray, guide: np.ndarray, smooth: float, scale: float = 100.0) -> np.ndarray:
    """Binary labelling ``(H, W)`` bool minimising sum(unary cost) + smooth * contrast-sensitive Potts
    (4-neighbours, weight ``exp(-beta |guide_p - guide_q|^2)``, beta from the mean contrast) by an
    s-t minimum cut (``scipy.sparse.csgraph.maximum_flow``, integer capacities: costs times
    ``scale``). ``unary > 0`` favours foreground by that much (the cost of labelling it background)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import breadth_first_order, maximum_flow

    h, w = unary.shape
    n = h * w
    src, snk = n, n + 1
    idx = np.arange(n).reshape(h, w)
    g = np.asarray(guide, np.float32).reshape(h, w, -1)
    rows, cols, caps = [np.full(n, src), idx.ravel()], [idx.ravel(), np.full(n, snk)], [np.maximum(unary, 0).ravel(), np.maximum(-unary, 0).ravel()]
    pairs = [(idx[:, :-1], idx[:, 1:], ((g[:, :-1] - g[:, 1:]) ** 2).sum(-1)), (idx[:-1], idx[1:], ((g[:-1] - g[1:]) ** 2).sum(-1))]
    beta = 1.0 / (2.0 * max(float(np.mean(np.concatenate([d.ravel() for _, _, d in pairs]))), 1e-6))
    for a, b, d in pairs:
        wgt = (smooth * np.exp(-beta * d)).ravel()
        rows += [a.ravel(), b.ravel()]
        cols += [b.ravel(), a.ravel()]
        caps += [wgt, wgt]
    cap = np.rint(np.concatenate(caps) * scale).astype(np.int32)
    keep = cap > 0
    graph = sp.csr_matrix((cap[keep], (np.concatenate(rows)[keep], np.concatenate(cols)[keep])), shape=(n + 2, n + 2))
    left = graph - maximum_flow(graph, src, snk, method="dinic").flow
    left.data = np.maximum(left.data, 0)
    left.eliminate_zeros()
    fg = np.zeros(n + 2, bool)
    fg[breadth_first_order(left, src, directed=True, return_predecessors=False)] = True
    return fg[:n].reshape(h, w)


def _equalised_lab(frame: np.ndarray, samples: int = 1 << 17) -> np.ndarray:
    """``frame (H, W, 3)`` with each channel replaced by its rank in the frame (a monotone map, so
    another exposure through any camera curve gives the same colours up to clipping), in CIELAB."""
    import cv2

    from layercam.flow import _midrank

    f = np.asarray(frame, np.float32)
    out = np.stack([np.clip(_midrank(f[..., c], samples), 0, 1) for c in range(3)], -1).astype(np.float32)
    return cv2.cvtColor(out, cv2.COLOR_RGB2Lab)


_BINS = 16  # colour histogram bins per CIELAB axis


def _colour_bins(lab: np.ndarray) -> np.ndarray:
    b = _BINS
    lq = np.clip(lab[..., 0] / 100 * b, 0, b - 1).astype(np.int32)
    aq = np.clip((lab[..., 1] + 100) / 200 * b, 0, b - 1).astype(np.int32)
    bq = np.clip((lab[..., 2] + 100) / 200 * b, 0, b - 1).astype(np.int32)
    return (lq * b + aq) * b + bq


def colour_cut(frames: np.ndarray, masks: np.ndarray, residual: np.ndarray, cfg: SegmentConfig | None = None, failure: np.ndarray | None = None) -> np.ndarray:
    """Masks ``(T, H, W)`` grown to the whole object by its colours (``segment.colour``): the
    motion masks find where the object is, often only part of it (the flow of a running dog's head
    and legs is the background's); the object's colours, learned over the whole clip, find the rest.

    A colour histogram of the object (the masks, eroded) and one of the background (outside them,
    dilated), over every frame (colours rank-equalised per frame and channel, so every exposure of an
    alternating clip reads alike; CIELAB, 16 bins an axis), give each pixel the log-likelihood
    ratio object : background. Per frame a graph cut (:func:`_graph_cut`; contrast-sensitive
    smoothness ``colour_smooth``) labels the pixels within ``colour_reach`` times the object's size
    (the square root of the clip's median mask area) of the mask, the mask counting +1 towards
    the object, and only where the frame differs from the background its neighbours show
    (``residual``, :func:`background_refine`'s relative residual, above ``colour``) or the mask
    already is: background of the object's colours does not join; each pixel pays
    ``colour_distance`` per object size it lies away from the mask (a near post that crosses the
    object does not run into the cut over the whole frame). With ``failure`` ``(T, H, W)``
    (:func:`layercam.motion.flow_failure`: where the flow loses a pixel within a few frames), each
    pixel counts ``colour_failure * (failure - 0.5)`` towards the object: a running dog's legs and
    head that the flow smooths into the background's motion are lost by it, a rigid post or
    trunk with parallax is followed. Then :func:`clean_mask`, which keeps
    parts of the object's colours within its size of the largest (an object an occluder splits);
    a cut that leaves nothing keeps the mask.
    Without the residual gate the cut spreads into background of the object's colours (the grey
    road beside a silver car). DAVIS at 282x158 (bootstrap IoU; docs/layers/colour/): car 0.767 ->
    0.808, cows 0.724 -> 0.764, libby 0.396 -> 0.535, parkour 0.766 -> 0.805; the distance cost and
    the split parts: libby 0.535 -> 0.562, the others unchanged; the flow's failure
    (docs/layers/failure/): car 0.808 -> 0.811, cows 0.765 -> 0.765, libby 0.572 -> 0.589, parkour
    0.808 -> 0.807."""
    import cv2

    cfg = cfg or SegmentConfig()
    m = np.asarray(masks) > 0.5
    T, h, w = m.shape
    area = m.reshape(T, -1).sum(1)
    if not (area > 0).any():
        return m
    ref = float(np.median(area[area > 0]))
    bins = np.stack([_colour_bins(_equalised_lab(f)).astype(np.uint16) for f in frames])  # 2 bytes a pixel: long 1080p clips fit
    k7 = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7))
    nb = _BINS**3
    fg_hist, bg_hist = np.ones(nb), np.ones(nb)
    for t in range(T):
        u = m[t].astype(np.uint8)
        fg_hist += np.bincount(bins[t][cv2.erode(u, k7) > 0], minlength=nb)
        bg_hist += np.bincount(bins[t][cv2.dilate(u, k7, iterations=3) == 0], minlength=nb)
    llr = np.clip(np.log(fg_hist / fg_hist.sum()) - np.log(bg_hist / bg_hist.sum()), -4.0, 4.0).astype(np.float32)
    size = np.sqrt(ref)
    rad = max(2.0, cfg.colour_reach * size)
    out = m.copy()
    for t in range(T):
        prior = m[t]
        if area[t] < 16:
            continue
        away = cv2.distanceTransform((~prior).astype(np.uint8), cv2.DIST_L2, 5)  # from the mask, px
        region = (away <= rad) & ((np.asarray(residual[t], np.float32) > cfg.colour) | prior)
        ys, xs = np.nonzero(region)
        y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
        box = (slice(y0, y1), slice(x0, x1))
        unary = llr[bins[t][box]] + prior[box] - cfg.colour_distance * away[box] / size
        if failure is not None and cfg.colour_failure > 0:
            unary = unary + cfg.colour_failure * (np.asarray(failure[t][box], np.float32) - 0.5)
        unary = np.where(region[box], unary, -50.0).astype(np.float32)
        cut = np.zeros((h, w), bool)
        guide = _equalised_lab(frames[t])[box] / 100.0  # again, not kept from the histogram pass: 12 bytes a pixel of the clip
        cut[box] = _graph_cut(unary, guide, cfg.colour_smooth)
        cut = clean_mask(cut, cfg, colour=llr[bins[t]], reach=size, scale=cfg.colour_clean)
        out[t] = cut if cut.any() else m[t]  # a cut that leaves nothing keeps the mask it had
    return out


SEGMENT_VERSION = 10              # bump when foreground_bootstrap changes the masks it returns (4: background_refine, 5: colour_cut, 6: its empty frames refilled along the flow, 7: its distance cost and split parts, 8: thin parts, 9: the flow's failure, 10: the colour cut cleaned at half radii)


def foreground_bootstrap(frames: np.ndarray, flows: dict | None, masks: np.ndarray | None = None, cfg: SegmentConfig | None = None, progress: bool = False) -> dict:
    """What a two-layer scene starts from: ``{"h0": (T, 3, 3), "masks": (T, H, W) | None,
    "computed": bool, "how": str, "info": dict}``.

    ``masks`` given by the user win; otherwise, with flow (``flows`` holds ``fw``, ``bw``,
    ``fw_ok``, ``homs`` as the flow stage caches them), motion masks refined by GrabCut, the
    background check and the colour cut, then, with ``cfg.detector``, a local Mask R-CNN's instances
    that lie in them (:mod:`layercam.detect`); with
    neither (one frame), no masks and the identity mapping.
    """
    cfg = cfg or SegmentConfig()
    T, h, w = frames.shape[:3]
    info: dict = {}
    computed = False
    if masks is None and flows is not None and T > 1:
        fw, bw = flows["fw"].astype(np.float32), flows["bw"].astype(np.float32)
        masks, info = motion_masks(fw, bw, flows.get("fw_ok"), flows.get("bw_ok"), cfg, frames=frames)
        if cfg.grabcut > 0:
            masks = np.stack([grabcut_refine(frames[t], masks[t], cfg.grabcut) for t in range(T)]).astype(np.float32)
            info["coverage_after_grabcut"] = float(masks.mean())
        if cfg.background > 0 and flows.get("homs") is not None:
            masks, rel = background_refine(frames, masks, flows["homs"], cfg)
            info["coverage_after_background"] = float(masks.mean())
            if cfg.colour > 0:  # frames the checks emptied start again from their neighbours'
                failure = None
                if cfg.colour_failure > 0:
                    from layercam.motion import flow_failure

                    failure = flow_failure(fw, bw, *_flow_checks(fw, bw, flows.get("fw_ok"), flows.get("bw_ok")))
                masks = colour_cut(frames, _fill_still_frames(masks, fw, bw, cfg.still_fraction)[0], rel, cfg, failure)
                info["coverage_after_colour"] = float(masks.mean())
            masks = masks.astype(np.float32)
        if cfg.detector:  # a local Mask R-CNN's instances where they lie in the motion masks
            from layercam.detect import detect_instances, pick_instances

            found = detect_instances(frames, cfg.detector, cfg.detector_score, cfg.detector_size, progress)
            masks, picked = pick_instances(found, masks, cfg.detector_overlap)
            info.update(picked, coverage_after_detector=float(masks.mean()))
        computed = True
    fw = flows["fw"].astype(np.float32) if flows is not None and T > 1 else None
    fw_ok = flows.get("fw_ok") if flows is not None else None
    if masks is None:
        h0, desc = foreground_mappings(h, w, np.zeros((T, h, w), np.float32), how="identity")
    else:
        h0, desc = foreground_mappings(h, w, masks, fw, fw_ok, cfg.margin, how=cfg.foreground)
    return {"h0": h0, "masks": masks, "computed": computed, "how": desc, "info": info}


def sure_pixels(masks: np.ndarray, band: float, out=None) -> np.ndarray:
    """Where masks ``(T, H, W)`` are trusted: pixels farther than ``band`` (a share of the short
    side) from the other class, so a band around each mask's edge is left out. A frame without any
    mask pixel is sure everywhere. ``out``: a ``(T, H, W)`` bool array to fill (a
    :class:`~layercam.io.frames.DiskArray` for a long clip), returned."""
    import cv2

    px = band * min(masks.shape[1:])
    if out is None:
        out = np.ones(masks.shape, dtype=bool)
    if px <= 0:
        out[0 : len(out)] = True
        return out
    for t in range(len(masks)):  # a frame at a time (masks and out may be on disk)
        f = np.asarray(masks[t]) > 0.5
        if not f.any() or f.all():
            out[t] = True
        else:
            u = f.astype(np.uint8)
            d_in = cv2.distanceTransform(u, cv2.DIST_L2, 3)       # inside: distance to the nearest outside pixel
            d_out = cv2.distanceTransform(1 - u, cv2.DIST_L2, 3)  # outside: to the nearest mask pixel
            out[t] = np.where(f, d_in, d_out) > px
    return out


def load_masks(folder) -> np.ndarray | None:
    """The masks :func:`save_masks` wrote in ``folder``, ``(T, H, W)`` float32 in {0, 1} (a long
    clip's, :func:`foreground_bootstrap_long`: a uint8 :class:`~layercam.io.frames.DiskArray` of
    0 and 1, read as needed); None without."""
    import json
    from pathlib import Path

    from layercam.io.frames import DiskArray

    raw = Path(folder) / "masks.raw"
    if raw.exists():
        return DiskArray(raw, np.uint8, json.loads((Path(folder) / "masks.json").read_text())["shape"])
    path = Path(folder) / "masks.npz"
    if not path.exists():
        return None
    with np.load(path) as z:
        return z["masks"].astype(np.float32)


def save_masks(folder, masks: np.ndarray) -> None:
    """``masks.npz`` (what training reads; a long clip's are in ``masks.raw`` already, written by
    :func:`foreground_bootstrap_long`) and ``masks/frame_00000.png`` (to look at) in ``folder``."""
    from pathlib import Path

    from layercam.io import write_png
    from layercam.io.frames import DiskArray

    folder = Path(folder)
    if not isinstance(masks, DiskArray):
        np.savez_compressed(folder / "masks.npz", masks=(np.asarray(masks) > 0.5))
    (folder / "masks").mkdir(exist_ok=True)
    for t in range(len(masks)):
        write_png(folder / "masks" / f"frame_{t:05d}.png", (np.asarray(masks[t]) > 0.5).astype(np.float32))


def mask_coverage(masks) -> np.ndarray:
    """Per frame ``(T,)``: the share of the frame the mask covers (read a frame at a time)."""
    return np.array([float(np.mean(np.asarray(masks[t]) > 0.5)) for t in range(len(masks))])


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


def foreground_bootstrap_long(frames, flows: dict, out, masks=None, cfg: SegmentConfig | None = None, progress: bool = False) -> dict:
    """:func:`foreground_bootstrap` for a long clip or one larger than the flow's working grid
    (:func:`windowed`), with the memory of a ``SEG_FRAMES``-frame clip on that grid: each window of
    :func:`segment_windows` is segmented on the flow's grid (its frames scaled to it, its flows as
    the flow stage keeps them), each frame's mask taken from the window it is the middle of, scaled
    up to the frames' size (bilinear, at 0.5) and written to ``out/masks.raw`` (uint8,
    :func:`load_masks` reads it); then the foreground mapping from all of them and the flows, read a
    frame or a pair at a time. ``flows`` as the flow stage keeps them (possibly at a working size
    and on disk); ``masks`` given by the user are not segmented again. Returns what
    :func:`foreground_bootstrap` does, ``masks`` the ``DiskArray``."""
    import json
    from pathlib import Path

    import cv2

    from layercam.flow import AtFrameSize
    from layercam.interrupts import reached
    from layercam.io.frames import DiskArray
    from layercam.progress import bar

    cfg = cfg or SegmentConfig()
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
        small = lambda f: f if f.shape[:2] == (h, w) else cv2.resize(f, (w, h), interpolation=cv2.INTER_AREA)  # noqa: E731
        for i, (a0, b0, a, b) in enumerate(bar(wins, desc="bootstrap (windows)", unit="window", enabled=progress and len(wins) > 1)):
            reached("segment", i)
            fl = {k: np.asarray(flows[k][a0 : b0 - 1]) for k in ("fw", "bw", "fw_ok", "bw_ok", "vis") if k in flows}
            fl["homs"] = np.asarray(flows["homs"])[a0 : b0 - 1]
            part = foreground_bootstrap(np.stack([small(frames[t]) for t in range(a0, b0)]), fl, None, cfg)  # a full-size frame at a time
            for t in range(a, b):
                m = np.asarray(part["masks"][t - a0], np.float32)
                masks[t] = (m if (h, w) == (H, W) else cv2.resize(m, (W, H), interpolation=cv2.INTER_LINEAR)) > 0.5
            models.append(part["info"].get("model"))
            del part, fl
        masks.flush()
        cover = mask_coverage(masks)
        info = {"windows": len(wins), "window_frames": SEG_FRAMES, "window_margin": SEG_MARGIN, "grid": [h, w], "models": models,
                "coverage_mean": float(cover.mean()), "coverage_min": float(cover.min()), "coverage_max": float(cover.max()), "empty_frames": int((cover == 0).sum())}
    fw, fw_ok = AtFrameSize(flows["fw"], (H, W)), AtFrameSize(flows["fw_ok"], (H, W))
    h0, desc = foreground_mappings(H, W, masks, fw, fw_ok, cfg.margin, how=cfg.foreground)
    return {"h0": h0, "masks": masks, "computed": computed, "how": desc, "info": info}
