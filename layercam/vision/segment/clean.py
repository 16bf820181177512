"""Shared mask cleaning: one object per frame, and frames without evidence filled along the flow.

Radii and sizes scale with the frame: the opening is ``OPEN`` of the short side, the closing twice
that; parts smaller than ``MIN_AREA`` of the frame or ``KEEP_FRACTION`` of the largest go, and so do
parts farther than ``GAP`` times the largest part's size (the square root of its area) from it.
"""

from __future__ import annotations

import numpy as np

OPEN = 0.01          # the opening's radius, a share of the short side (the closing's is twice it)
MIN_AREA = 0.002     # a part smaller than this share of the frame is a speck
KEEP_FRACTION = 0.15  # ... and one smaller than this share of the largest part is not the object
GAP = 0.25           # parts an occluder splits off lie within this many object sizes of the largest
THIN_LLR = 3.0       # a thin part the opening took comes back where its ratio is this high


def part_means(lab: np.ndarray, n: int, values: np.ndarray) -> np.ndarray:
    """Mean of ``values (H, W)`` over each of the ``n`` labels of ``lab`` (0 included) ``(n,)``."""
    return np.bincount(lab.ravel(), weights=np.asarray(values, np.float64).ravel(),
                       minlength=n) / np.maximum(np.bincount(lab.ravel(), minlength=n), 1)


def mask_parts(mask: np.ndarray, colour: np.ndarray | None = None,
               scale: float = 1.0) -> tuple[int, np.ndarray, np.ndarray]:
    """The parts :func:`clean_mask` chooses among: ``mask`` ``(H, W)`` opened, closed and its holes
    filled (``colour`` and ``scale`` as there), then its connected components: ``(n, labels (H, W),
    areas (n - 1,))``, label 0 the background."""
    import cv2

    h, w = mask.shape
    m = mask.astype(np.uint8)
    r = max(1, int(round(OPEN * min(h, w))))
    ro, rc = int(round(scale * r)), int(round(scale * 2 * r))
    if ro > 0:
        m = cv2.morphologyEx(m, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * ro + 1, 2 * ro + 1)))
    if colour is not None:
        thin = (mask.astype(bool) & (m == 0) & (np.asarray(colour) >= THIN_LLR)).astype(np.uint8)
        nt, lt = cv2.connectedComponents(m | thin, connectivity=8)
        m = (part_means(lt, nt, m) > 0)[lt].astype(np.uint8)
    if rc > 0:
        m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * rc + 1, 2 * rc + 1)))
    flood = np.pad(m, 1).copy()  # fill holes: background is what the border reaches
    cv2.floodFill(flood, np.zeros((h + 4, w + 4), np.uint8), (0, 0), 1)
    m = (m.astype(bool) | (flood[1:-1, 1:-1] == 0)).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    return n, lab, stats[1:, cv2.CC_STAT_AREA]


def clean_mask(mask: np.ndarray, colour: np.ndarray | None = None, scale: float = 1.0,
               seed: np.ndarray | None = None) -> np.ndarray:
    """Morphology on one ``(H, W)`` bool mask: open, close, fill holes, drop small components, and
    keep one object: the largest component and those within ``GAP`` times its size of it (parts an
    occluder splits off). With ``colour`` (``(H, W)``, the object : background colour
    log-likelihood ratio of :func:`layercam.vision.segment.colour.colour_cut`), what the opening took
    comes back where its ratio is at least ``THIN_LLR`` and it touches what the opening left (legs,
    a tail). ``scale``: the radii of the opening and the closing times this (0: neither). With
    ``seed`` (``(H, W)`` bool: the mask a cut grew from, or the part a followed track holds), the
    part kept is the one that holds most of it, whatever its size (a cut grows the object; a larger
    part it found apart from it is not the object), or the largest where none does."""
    return keep_object(mask_parts(mask, colour, scale), seed)


def keep_object(parts: tuple[int, np.ndarray, np.ndarray], seed: np.ndarray | None = None) -> np.ndarray:
    """:func:`clean_mask`'s choice of parts, ``(H, W)`` bool, on parts already cut by
    :func:`mask_parts` (``(n, labels, areas)``); ``seed`` as there."""
    import cv2
    from scipy import ndimage

    n, lab, areas = parts
    h, w = lab.shape
    if n <= 1:
        return np.zeros((h, w), bool)
    keep = (areas >= MIN_AREA * h * w) & (areas >= KEEP_FRACTION * areas.max())
    main = 1 + int(np.argmax(areas))
    if seed is not None:
        held = ndimage.sum(np.asarray(seed, np.float64), lab, np.arange(1, n))
        if held.max() > 0:
            main = 1 + int(np.argmax(held))
            keep[main - 1] = True
    if keep.sum() > 1:
        dist = cv2.distanceTransform((lab != main).astype(np.uint8), cv2.DIST_L2, 3)
        gaps = ndimage.minimum(dist, lab, np.arange(1, n))
        keep &= gaps <= GAP * np.sqrt(areas.max())
    return np.isin(lab, 1 + np.flatnonzero(keep))


def warp_mask(mask: np.ndarray, flow_t: np.ndarray) -> np.ndarray:
    """``mask`` of frame t+-1 brought into frame t along ``flow_t`` (t's pixels -> the other's), float."""
    from layercam.core.geometry import warp

    return warp(np.asarray(mask, np.float32), flow_t, border="constant")


STILL = 0.3  # a frame whose mask is under this share of the clip's median area has lost the object


def fill_still_frames(masks: np.ndarray, fw: np.ndarray, bw: np.ndarray,
                      frac: float | None = None) -> tuple[np.ndarray, list[int]]:
    """Frames whose mask is under ``frac`` (default ``STILL``) of the clip's median area inherit the
    mask of the nearest frame that holds the object at its typical size (at least the median area),
    carried along the flow. (Not the nearest frame over ``frac``: where an object starts or stops
    moving, the frames beside the still ones see only the parts that move, and their partial masks
    would be carried through every still frame.)"""
    frac = STILL if frac is None else frac
    T = masks.shape[0]
    area = masks.reshape(T, -1).sum(1)
    ref = float(np.median(area[area > 0])) if (area > 0).any() else 0.0
    if ref <= 0:
        return masks, []
    good = area >= frac * ref
    typical = np.flatnonzero(area >= ref)  # never empty: some frame reaches the median
    out = masks.copy()
    filled = []
    for t in np.flatnonzero(~good):
        s = int(typical[np.argmin(np.abs(typical - t))])  # the nearest (the earlier on a tie)
        m = masks[s].astype(np.float32)
        if s > t:
            for j in range(s - 1, t - 1, -1):
                m = warp_mask(m, fw[j])
        else:
            for j in range(s, t):
                m = warp_mask(m, bw[j])
        out[t] = m > 0.5
        filled.append(int(t))
    return out, filled


LOST = 0.7  # a mask under this share of its neighbour's, carried along the flow, has lost part of the object


def carry_lost(masks: np.ndarray, fw: np.ndarray, bw: np.ndarray, likely: np.ndarray) -> np.ndarray:
    """Where frames lost part of the object: ``(T, H, W)`` bool, the pixels a neighbour's mask
    carried along the flow adds to a frame whose own mask ``masks`` is under ``LOST`` of it (empty
    elsewhere). Walks outward from the frame with the largest mask; what is carried on from a frame
    is its own mask and the carried pixels of the object's colours (``likely``, ``(T, H, W)``
    bool), so an object lost for several frames is carried through them and the background a
    carried mask overlaps is not."""
    m = np.asarray(masks) > 0.5
    T = m.shape[0]
    extra = np.zeros_like(m)
    if T < 2 or not m.any():
        return extra
    chain = m.copy()
    start = int(np.argmax(m.reshape(T, -1).sum(1)))
    for step in (1, -1):
        for t in range(start, T - 1 if step == 1 else 0, step):
            n = t + step
            carried = warp_mask(chain[t], bw[t] if step == 1 else fw[n]) > 0.5
            if m[n].sum() < LOST * carried.sum():
                extra[n] = carried & ~m[n]
                chain[n] = m[n] | (extra[n] & likely[n])
    return extra
