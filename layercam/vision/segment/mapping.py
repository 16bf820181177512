"""The foreground layer's bootstrap mapping: the object's own motion (a similarity per frame pair
fitted to the flow inside its mask, chained to a reference frame), scaled so that the object fills
the foreground atlas.

Shapes: flows ``(T-1, H, W, 2)`` in pixels, masks ``(T, H, W)``, mappings ``(T, 3, 3)``.
"""

from __future__ import annotations

import numpy as np

from layercam.core.errors import LayercamError


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
            a, _ = cv2.estimateAffinePartial2D(src, src + d, method=cv2.RANSAC,
                                               ransacReprojThreshold=1.0, maxIters=2000,
                                               confidence=0.995)
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


def foreground_mappings(h: int, w: int, masks: np.ndarray, fw=None, fw_ok=None, *, margin: float,
                        how: str) -> tuple[np.ndarray, str]:
    """The foreground layer's ``h0`` ``(T, 3, 3)``: normalised frame coordinates -> atlas uv.

    how "object": the object's own chained motion (:func:`object_motion`) to the frame where the
    mask is largest, scaled isotropically so that the union of the mapped masks fills
    ``[-margin, margin]^2`` (the rest of the atlas is slack for what the masks missed).
    how "identity": every frame maps the same way (the paper's start), whole frame in the atlas.
    """
    from layercam.core.geometry import atlas_mappings, chain_homographies, fit_into_atlas

    T = masks.shape[0]
    if how == "identity" or fw is None or T < 2:
        return atlas_mappings(h, w, np.stack([np.eye(3)] * T)), "identity"
    # a frame at a time (masks may be on disk)
    area = np.array([np.count_nonzero(np.asarray(masks[t]) > 0.5) for t in range(T)])
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
        # the pixel's square's centre (geometry.atlas_box)
        p = pix[t] @ np.stack([xs + 0.5, ys + 0.5, np.ones_like(xs, dtype=np.float64)])
        pts.append((p[:2] / p[2:]).T)
    pts = np.concatenate(pts)
    lo, hi = np.percentile(pts, 1, axis=0), np.percentile(pts, 99, axis=0)
    return fit_into_atlas(pix, (lo + hi) / 2, max((hi - lo).max() / 2, 2.0), margin, h,
                          w), f"object motion chained to frame {ref}"
