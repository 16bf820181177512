"""Step 6: the masks grown to the whole object by its colours learned over the clip: the motion
masks find where the object is, often only part of it (the flow of a running dog's head and legs
is the background's).

A colour histogram of the object (the masks, eroded) and one of the background (outside them,
dilated), over every frame (colours rank-equalised per frame and channel, so every exposure of an
alternating clip reads alike; CIELAB, ``BINS`` an axis), give each pixel the log-likelihood ratio
object : background. Per frame a graph cut (:func:`graph_cut`; contrast-sensitive smoothness
``SMOOTH``) labels the pixels within ``REACH`` times the object's size (the square root of the
clip's median mask area) of the mask, the mask counting +1 towards the object, and only where the
frame differs from the clean plate (:func:`layercam.vision.segment.background.background_refine`'s
relative residual, above ``GATE``) or the mask already is: background of the object's colours
does not join. Each pixel pays ``DISTANCE`` per object size it lies away from the mask. A frame
whose mask lost part of the object (under ``clean.LOST`` of its neighbour's carried along the flow,
as when the object moves the way the camera does and no motion test can see it) may take the
carried pixels by their colours alone, wherever the residual is (the clean plate behind it may
hold the object too). Then :func:`layercam.vision.segment.clean.clean_mask` at half its radii (legs
and tails 1-3 px wide) keeps the part that holds most of the mask the cut grew from (not the
largest: a cut that reaches a larger moving thing apart from the object, a flower pot by the lens,
a stream, grows the object and must not trade it for that), with the parts an occluder split off
it; a cut that leaves nothing keeps the mask.
"""

from __future__ import annotations

import numpy as np

from layercam.vision.segment.clean import clean_mask

BINS = 16        # colour histogram bins per CIELAB axis
GATE = 0.3       # the relative residual against the clean plate where the cut may add pixels
REACH = 2.0      # how far from the mask the cut looks, in object sizes
SMOOTH = 2.0     # the cut's weight on following colour edges
DISTANCE = 1.0   # the cost per object size away from the mask
CLEAN = 0.5      # the cleaning's radii, a share of clean_mask's


def graph_cut(unary: np.ndarray, guide: np.ndarray, smooth: float, scale: float = 100.0) -> np.ndarray:
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
    rows, cols, caps = [np.full(n, src), idx.ravel()], [idx.ravel(),
                        np.full(n, snk)], [np.maximum(unary, 0).ravel(),
                        np.maximum(-unary, 0).ravel()]
    pairs = [(idx[:, :-1], idx[:, 1:], ((g[:, :-1] - g[:, 1:]) ** 2).sum(-1)),
             (idx[:-1], idx[1:], ((g[:-1] - g[1:]) ** 2).sum(-1))]
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


def equalised_lab(frame: np.ndarray, samples: int = 1 << 17) -> np.ndarray:
    """``frame (H, W, 3)`` with each channel replaced by its rank in the frame (a monotone map, so
    another exposure through any camera curve gives the same colours up to clipping), in CIELAB."""
    import cv2

    from layercam.vision.flow_input import midrank

    f = np.asarray(frame, np.float32)
    out = np.stack([np.clip(midrank(f[..., c], samples), 0, 1) for c in range(3)], -1).astype(np.float32)
    return cv2.cvtColor(out, cv2.COLOR_RGB2Lab)


def colour_bins(lab: np.ndarray) -> np.ndarray:
    b = BINS
    lq = np.clip(lab[..., 0] / 100 * b, 0, b - 1).astype(np.int32)
    aq = np.clip((lab[..., 1] + 100) / 200 * b, 0, b - 1).astype(np.int32)
    bq = np.clip((lab[..., 2] + 100) / 200 * b, 0, b - 1).astype(np.int32)
    return (lq * b + aq) * b + bq


def colour_ratio(bins: np.ndarray, masks: np.ndarray, away: np.ndarray) -> np.ndarray:
    """Object : background colour log-likelihood ratio per bin ``(BINS**3,)``: the object's
    histogram from ``masks`` eroded, the background's from outside ``away`` dilated (both
    ``(T, H, W)`` bool, over every frame; ``bins`` ``(T, H, W)`` from :func:`colour_bins`)."""
    import cv2

    k7 = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7))
    nb = BINS**3
    fg_hist, bg_hist = np.ones(nb), np.ones(nb)
    for t in range(len(bins)):
        fg_hist += np.bincount(bins[t][cv2.erode(masks[t].astype(np.uint8), k7) > 0], minlength=nb)
        bg_hist += np.bincount(bins[t][cv2.dilate(away[t].astype(np.uint8), k7, iterations=3) == 0], minlength=nb)
    return np.clip(np.log(fg_hist / fg_hist.sum()) - np.log(bg_hist / bg_hist.sum()), -4.0, 4.0).astype(np.float32)


def colour_cut(frames: np.ndarray, masks: np.ndarray, residual: np.ndarray,
               fw: np.ndarray | None = None, bw: np.ndarray | None = None) -> np.ndarray:
    """Masks ``(T, H, W)`` bool grown to the whole object by its colours (module docstring).
    ``residual (T, H, W)``: the relative residual against the clean plate; ``fw``, ``bw``
    ``(T-1, H, W, 2)``: the flow that carries a mask into a frame that lost part of the object
    (:func:`layercam.vision.segment.clean.carry_lost`): the cut may add the carried pixels at no
    distance cost and without the residual, by their colours alone (without flow nothing is carried)."""
    import cv2

    from layercam.vision.segment.clean import carry_lost

    m = np.asarray(masks) > 0.5
    T, h, w = m.shape
    area = m.reshape(T, -1).sum(1)
    if not (area > 0).any():
        return m
    ref = float(np.median(area[area > 0]))
    # 2 bytes a pixel: long 1080p clips fit
    bins = np.stack([colour_bins(equalised_lab(f)).astype(np.uint16) for f in frames])
    llr = colour_ratio(bins, m, m)
    carried = np.zeros_like(m) if fw is None else carry_lost(m, fw, bw, (llr > 0)[bins])
    if carried.any():  # the carried pixels are not counted as background
        llr = colour_ratio(bins, m, m | carried)
    size = np.sqrt(ref)
    rad = max(2.0, REACH * size)
    out = m.copy()
    for t in range(T):
        prior = m[t]
        if area[t] < 16:
            continue
        may = prior | carried[t]
        away = cv2.distanceTransform((~may).astype(np.uint8), cv2.DIST_L2, 5)  # from the mask, px
        region = (away <= rad) & ((np.asarray(residual[t], np.float32) > GATE) | may)
        ys, xs = np.nonzero(region)
        y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
        box = (slice(y0, y1), slice(x0, x1))
        unary = llr[bins[t][box]] + prior[box] - DISTANCE * away[box] / size
        unary = np.where(region[box], unary, -50.0).astype(np.float32)
        cut = np.zeros((h, w), bool)
        guide = equalised_lab(frames[t])[box] / 100.0  # again, not kept from the histogram pass: 12
                                                       # bytes a pixel of the clip
        cut[box] = graph_cut(unary, guide, SMOOTH)
        cut = clean_mask(cut, colour=llr[bins[t]], scale=CLEAN, seed=prior)
        out[t] = cut if cut.any() else m[t]  # a cut that leaves nothing keeps the mask it had
    return out
