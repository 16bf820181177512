"""Step 6: the masks grown to the whole object by its colours learned over the clip: the motion
masks find where the object is, often only part of it (the flow of a running dog's head and legs
is the background's).

A colour histogram of the object (the masks, eroded) and one of the background (outside them,
dilated), over every frame (colours rank-equalised per frame and channel, so every exposure of an
alternating clip reads alike; CIELAB, ``BINS`` an axis), give each pixel the log-likelihood ratio
object : background. One graph cut over the whole clip (:func:`graph_cut`; contrast-sensitive
smoothness ``SMOOTH``) labels, in each frame, the pixels within ``REACH`` times the object's size
(the square root of the clip's median mask area) of the mask, the mask counting +1 towards the
object, and only where the frame differs from the clean plate
(:func:`layercam.vision.segment.background.background_refine`'s relative residual, above ``GATE``)
or the mask already is: background of the object's colours does not join. Each pixel pays
``DISTANCE`` per object size it lies away from the mask. The frames are joined along the flow
(:func:`temporal_links`: Papazoglou & Ferrari 2013's spatio-temporal cut, the temporal terms
weighted as the spatial ones), so a frame whose own evidence is weak is labelled as its
neighbours' say the pixels it shares with them are, and a stray part one frame takes does not
survive its neighbours' disagreement. A frame
whose mask lost part of the object (under ``clean.LOST`` of its neighbour's carried along the flow,
as when the object moves the way the camera does and no motion test can see it) may take the
carried pixels by their colours alone, wherever the residual is (the clean plate behind it may
hold the object too). Then :func:`layercam.vision.segment.clean.clean_mask` at half its radii (legs and tails 1-3 px wide),
keeping parts of the object's colours within its size of the largest; a cut that leaves nothing
keeps the mask.
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


def _contrast(guide: np.ndarray) -> tuple[list, float]:
    """One frame's 4-neighbour pairs ``[(a, b, |guide_a - guide_b|^2)]`` (``a``, ``b`` flat indices
    into ``guide (h, w, C)``) and the contrast-sensitive Potts weight's beta (from their mean)."""
    h, w = guide.shape[:2]
    idx = np.arange(h * w, dtype=np.int32).reshape(h, w)
    pairs = [(idx[:, :-1], idx[:, 1:], ((guide[:, :-1] - guide[:, 1:]) ** 2).sum(-1)), (idx[:-1], idx[1:], ((guide[:-1] - guide[1:]) ** 2).sum(-1))]
    return pairs, 1.0 / (2.0 * max(float(np.mean(np.concatenate([d.ravel() for _, _, d in pairs]))), 1e-6))


def graph_cut(unary, guide, smooth: float, scale: float = 100.0, links=None, free=None):
    """Binary labelling minimising sum(unary cost) + smooth * contrast-sensitive Potts (4-neighbours,
    weight ``exp(-beta |guide_p - guide_q|^2)``, beta from the frame's mean contrast) by an s-t minimum
    cut (``scipy.sparse.csgraph.maximum_flow``, integer capacities: costs times ``scale``).
    ``unary > 0`` favours foreground by that much (the cost of labelling it background).

    ``unary (H, W)`` and ``guide (H, W, C)`` give ``(H, W)`` bool; lists of them (frames of any sizes)
    are labelled together and give a list, ``links`` then joining them: ``(frame a, flat index,
    frame b, flat index, weight)`` arrays, a Potts term of ``weight`` between each such pair of
    pixels (the spatio-temporal cut's edges along the flow, :func:`temporal_links`). ``free`` (bool
    like ``unary``, or a list): the pixels to label; the others are background, and only what their
    Potts terms cost a free neighbour labelled foreground enters the cut (a smaller graph, the same
    labelling as a unary that forbids them)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import breadth_first_order, maximum_flow

    one = not isinstance(unary, (list, tuple))
    unaries = [unary] if one else list(unary)
    guides = [guide] if one else list(guide)
    frees = [np.ones(u.shape, bool) for u in unaries] if free is None else ([free] if one else list(free))
    node, n = [], 0  # each frame's pixels' node numbers, -1 where fixed to background
    for f in frees:
        ids = np.full(f.size, -1, np.int32)
        ids[f.ravel()] = n + np.arange(np.count_nonzero(f), dtype=np.int32)
        node.append(ids)
        n += np.count_nonzero(f)
    src, snk = n, n + 1
    to_bg, to_fg = np.zeros(n), np.zeros(n)  # each node's cost of background, of foreground
    ea, eb, ew = [], [], []

    def potts(na, nb, wgt):
        both = (na >= 0) & (nb >= 0)
        ea.append(na[both])
        eb.append(nb[both])
        ew.append(wgt[both].astype(np.float32))
        for x, y in ((na, nb), (nb, na)):  # a free pixel beside a fixed one pays the term as foreground
            one_side = (x >= 0) & (y < 0)
            np.add.at(to_fg, x[one_side], wgt[one_side])

    for ids, u, g in zip(node, unaries, guides):
        uf = u.ravel()
        keep = ids >= 0
        to_bg[ids[keep]] += np.maximum(uf[keep], 0)
        to_fg[ids[keep]] += np.maximum(-uf[keep], 0)
        pairs, beta = _contrast(np.asarray(g, np.float32).reshape(*u.shape, -1))
        for a, b, d in pairs:
            potts(ids[a.ravel()], ids[b.ravel()], (smooth * np.exp(-beta * d)).ravel())
    for fa, ia, fb, ib, wgt in links or ():
        potts(node[fa][ia], node[fb][ib], np.asarray(wgt, np.float64))
    a, b, wgt = np.concatenate(ea), np.concatenate(eb), np.rint(np.concatenate(ew) * scale).astype(np.int32)
    del ea, eb, ew
    nodes = np.arange(n, dtype=np.int32)
    rows = np.concatenate([np.full(n, src, np.int32), nodes, a, b])
    cols = np.concatenate([nodes, np.full(n, snk, np.int32), b, a])
    cap = np.concatenate([np.rint(to_bg * scale).astype(np.int32), np.rint(to_fg * scale).astype(np.int32), wgt, wgt])
    del a, b, wgt, nodes
    keep = cap > 0
    graph = sp.csr_matrix((cap[keep], (rows[keep], cols[keep])), shape=(n + 2, n + 2))
    del rows, cols, cap, keep
    left = graph - maximum_flow(graph, src, snk, method="dinic").flow
    del graph
    left.data = np.maximum(left.data, 0)
    left.eliminate_zeros()
    fg = np.zeros(n + 2, bool)
    fg[breadth_first_order(left, src, directed=True, return_predecessors=False)] = True
    out = []
    for ids, u in zip(node, unaries):
        lab = np.zeros(u.size, bool)
        lab[ids >= 0] = fg[ids[ids >= 0]]
        out.append(lab.reshape(u.shape))
    return out[0] if one else out


def temporal_links(boxes: list, guides: list, fw: np.ndarray, fw_ok: np.ndarray, smooth: float) -> list:
    """The spatio-temporal cut's edges (Papazoglou & Ferrari 2013): each pixel of frame ``k``'s box
    joined to the pixel of frame ``k + 1``'s box its forward flow lands on, where the flow is
    forward-backward consistent, with the spatial term's weight ``smooth`` and its contrast
    sensitivity (the colours along the flow, frame ``k``'s beta). ``boxes``: per frame
    ``(t, y0, y1, x0, x1)`` (its frame and its box in it), ``guides`` its colours ``(y1-y0, x1-x0, C)``;
    ``fw (T-1, H, W, 2)``, ``fw_ok (T-1, H, W)``. Returns :func:`graph_cut`'s ``links``."""
    links = []
    for k in range(len(boxes) - 1):
        t, y0, y1, x0, x1 = boxes[k]
        t2, Y0, Y1, X0, X1 = boxes[k + 1]
        if t2 != t + 1:
            continue
        yy, xx = np.mgrid[y0:y1, x0:x1]
        f = np.asarray(fw[t][y0:y1, x0:x1], np.float32)
        qy, qx = np.rint(yy + f[..., 1]).astype(np.int64), np.rint(xx + f[..., 0]).astype(np.int64)
        ok = np.asarray(fw_ok[t][y0:y1, x0:x1], bool) & (qy >= Y0) & (qy < Y1) & (qx >= X0) & (qx < X1)
        if not ok.any():
            continue
        g, g2 = guides[k], guides[k + 1]
        d = ((g[ok] - g2[qy[ok] - Y0, qx[ok] - X0]) ** 2).sum(-1)
        beta = _contrast(g)[1]
        links.append((k, np.flatnonzero(ok.ravel()), k + 1, (qy[ok] - Y0) * (X1 - X0) + (qx[ok] - X0), smooth * np.exp(-beta * d)))
    return links


def equalised_lab(frame: np.ndarray, samples: int = 1 << 17) -> np.ndarray:
    """``frame (H, W, 3)`` with each channel replaced by its rank in the frame (a monotone map, so
    another exposure through any camera curve gives the same colours up to clipping), in CIELAB."""
    import cv2

    from layercam.vision.flow import _midrank

    f = np.asarray(frame, np.float32)
    out = np.stack([np.clip(_midrank(f[..., c], samples), 0, 1) for c in range(3)], -1).astype(np.float32)
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


def colour_cut(frames: np.ndarray, masks: np.ndarray, residual: np.ndarray, fw: np.ndarray | None = None, bw: np.ndarray | None = None, fw_ok: np.ndarray | None = None) -> np.ndarray:
    """Masks ``(T, H, W)`` bool grown to the whole object by its colours (module docstring).
    ``residual (T, H, W)``: the relative residual against the clean plate; ``fw``, ``bw``
    ``(T-1, H, W, 2)``: the flow that joins the frames' cuts into one (its forward-backward check
    ``fw_ok (T-1, H, W)``, computed when None) and carries a mask into a frame that lost part of the
    object (:func:`layercam.vision.segment.clean.carry_lost`): the cut may add the carried pixels at no
    distance cost and without the residual, by their colours alone (without flow each frame is cut
    on its own and nothing is carried)."""
    import cv2

    from layercam.vision.segment.clean import carry_lost

    m = np.asarray(masks) > 0.5
    T, h, w = m.shape
    area = m.reshape(T, -1).sum(1)
    if not (area > 0).any():
        return m
    ref = float(np.median(area[area > 0]))
    bins = np.stack([colour_bins(equalised_lab(f)).astype(np.uint16) for f in frames])  # 2 bytes a pixel: long 1080p clips fit
    llr = colour_ratio(bins, m, m)
    carried = np.zeros_like(m) if fw is None else carry_lost(m, fw, bw, (llr > 0)[bins])
    if carried.any():  # the carried pixels are not counted as background
        llr = colour_ratio(bins, m, m | carried)
    size = np.sqrt(ref)
    rad = max(2.0, REACH * size)
    unaries, guides, boxes, frees = [], [], [], []
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
        unaries.append(unary.astype(np.float32))
        frees.append(region[box])
        guides.append(equalised_lab(frames[t])[box] / 100.0)  # again, not kept from the histogram pass: 12 bytes a pixel of the clip
        boxes.append((t, y0, y1, x0, x1))
    if not boxes:
        return m
    links = None
    if fw is not None:
        if fw_ok is None:
            from layercam.vision.flow import flow_consistency

            fw_ok = flow_consistency(np.asarray(fw, np.float32), np.asarray(bw, np.float32))
        links = temporal_links(boxes, guides, fw, fw_ok, SMOOTH)
    cuts = graph_cut(unaries, guides, SMOOTH, links=links, free=frees)
    out = m.copy()
    for (t, y0, y1, x0, x1), c in zip(boxes, cuts):
        cut = np.zeros((h, w), bool)
        cut[y0:y1, x0:x1] = c
        cut = clean_mask(cut, colour=llr[bins[t]], reach=size, scale=CLEAN)
        out[t] = cut if cut.any() else m[t]  # a cut that leaves nothing keeps the mask it had
    return out
