"""Long-range motion evidence: what moves against the static scene consistently over many frames.

For every frame ``t`` and every offset ``k`` of ``offsets`` (both directions), each pixel is followed
to frame ``t +- k`` along the chained neighbour flows (valid while every step passes the
forward-backward check; at ``k = 1`` the raw flow counts everywhere, since a moving object often
fails the check), and its displacement is compared with the static scene's:

* a **homography** (RANSAC) when the scene is a plane or the camera only rotates;
* an **epipolar model** (fundamental matrix, RANSAC; residual = Sampson distance) when the clip has
  parallax: near background (a wall along the path, a fence, branches in front of the lens) moves
  differently from far background under a translating camera, but stays on its epipolar lines,
  which an object moving on its own leaves.

The fundamental matrix is also satisfied by an object that moves only along epipolar lines, and
when the background is one plane it is degenerate and can take in any object moving in a straight
line (a car tracked by a panning camera, a cow walking on a field). So a pair votes for it only when
the points it explains beyond the homography lie in regions that reach the frame's edge (near
background runs off the frame; an object seen whole does not), and the clip uses it only when at
least ``f_vote`` of its pairs vote so. Measured at 282x158 (DAVIS, DIS fast flow): parkour 0.98 of
pairs (the wall beside the path), libby 0.69 (branches, fence posts), car-roundabout 0.10, cows 0.

Per pair a pixel moves when its residual exceeds ``max(abs_px * sqrt(k), median + k_sigma * 1.4826
MAD)`` of the pair's residuals. The evidence of frame ``t`` is, per direction, the fraction of its
valid pairs in which the pixel moved (a pair ``k`` frames apart weighs ``sqrt(k)``: an object moving
0.5 px per frame leaves the model only over 4 and 8 frames); then the two directions' mean, but at
most twice the smaller: the background an object is about to cover or has just uncovered moves in
one direction only, while a slow object near the clip's end may lack the long pairs on one side. A slow object (0.1-0.2 px per frame) builds up evidence
over 8 frames; flicker (noise, water, reflections) does not add up along a consistent track.

Shapes: flows ``(T-1, H, W, 2)`` in pixels, validity ``(T-1, H, W)`` bool, evidence ``(T, H, W)``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["chained_displacements", "pair_residuals", "long_range_evidence", "flow_failure"]


def _grid(h: int, w: int) -> np.ndarray:
    from layercam.geometry import pixel_grid

    return np.stack(pixel_grid(h, w), -1)


def chained_displacements(fw: np.ndarray, bw: np.ndarray | None, fw_ok: np.ndarray, bw_ok: np.ndarray | None, t: int, kmax: int) -> dict:
    """``{k: (d (H, W, 2), valid (H, W))}`` for ``k = +-1 .. +-kmax`` inside the clip (forward only
    when ``bw`` is None): where each pixel
    of frame ``t`` lands in frame ``t + k`` along the chained flows (``fw[j]``: j -> j+1, ``bw[j]``:
    j+1 -> j), valid where every step lands inside the frame on a forward-backward consistent pixel."""
    import cv2

    T = fw.shape[0] + 1
    h, w = fw.shape[1:3]
    base = _grid(h, w)
    out = {}
    for sgn, flows, oks in ((1, fw, fw_ok), (-1, bw, bw_ok)) if bw is not None else ((1, fw, fw_ok),):
        d = np.zeros((h, w, 2), np.float32)
        v = np.ones((h, w), bool)
        j = t
        for k in range(1, kmax + 1):
            if not 0 <= j + sgn < T:
                break
            i = j if sgn > 0 else j - 1
            p = base + d
            f = cv2.remap(flows[i], p[..., 0], p[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=(np.nan, np.nan, np.nan, np.nan))
            ok = cv2.remap(oks[i].astype(np.float32), p[..., 0], p[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT) > 0.5
            v &= ok & np.isfinite(f).all(-1)
            d = d + np.nan_to_num(f)
            j += sgn
            out[sgn * k] = (d.copy(), v.copy())
    return out


def _sampson(f: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Sampson distance (px) of correspondences ``x1 -> x2`` ``(..., 2)`` to the epipolar geometry ``f``."""
    p1 = np.concatenate([x1, np.ones_like(x1[..., :1])], -1)
    p2 = np.concatenate([x2, np.ones_like(x2[..., :1])], -1)
    fx1, ftx2 = p1 @ f.T, p2 @ f
    num = (p2 * fx1).sum(-1) ** 2
    den = fx1[..., 0] ** 2 + fx1[..., 1] ** 2 + ftx2[..., 0] ** 2 + ftx2[..., 1] ** 2
    return np.sqrt(num / np.maximum(den, 1e-12))


def _edge_fraction(sel: np.ndarray, x2: np.ndarray) -> float:
    """Share of ``sel``'s area (``(H, W)`` bool, after a 3x3 opening) in connected regions that reach
    the frame's edge, or pixels whose match ``x2 (H, W, 2)`` leaves the other frame."""
    import cv2

    h, w = sel.shape
    m = cv2.morphologyEx(sel.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, lab, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    if n <= 1:
        return 0.0
    edge = ~((x2[..., 0] >= 0) & (x2[..., 0] <= w - 1) & (x2[..., 1] >= 0) & (x2[..., 1] <= h - 1))
    edge[0, :] = edge[-1, :] = edge[:, 0] = edge[:, -1] = True
    edge = cv2.dilate(edge.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    touch = np.zeros(n, bool)
    touch[np.unique(lab[edge])] = True
    touch[0] = False
    area = stats[:, cv2.CC_STAT_AREA]
    return float(area[touch].sum() / max(area[1:].sum(), 1))


def pair_residuals(d: np.ndarray, valid: np.ndarray, step: int = 4, ransac_px: float = 1.0, h_inliers: float = 0.8, f_gain: float = 0.1, edge: float = 0.5, seed: int = 0):
    """Residual motion of one frame pair: displacements ``d (H, W, 2)``, fitted where ``valid``.

    Returns ``(res_h, res_f, f_vote)``: the distance (px) to the homography fitted by RANSAC
    (``(H, W)``, None when the pair has too few valid pixels); the smaller of that and the Sampson
    distance to the fundamental matrix (None when the homography already explains at least
    ``h_inliers`` of the points, or the fundamental matrix adds fewer than ``f_gain`` of them); and
    whether the pair votes for the epipolar model (its extra points lie mostly, ``edge``, in regions
    that reach the frame's edge)."""
    import cv2

    h, w = d.shape[:2]
    x1 = _grid(h, w)
    x2 = x1 + d
    sv = valid[::step, ::step].ravel()
    if sv.sum() < 50:
        return None, None, False
    s1, s2 = x1[::step, ::step].reshape(-1, 2)[sv], x2[::step, ::step].reshape(-1, 2)[sv]
    cv2.setRNGSeed(seed)
    hm, inl = cv2.findHomography(s1, s2, cv2.RANSAC, ransac_px, maxIters=2000, confidence=0.995)
    if hm is None or not np.all(np.isfinite(hm)):
        return None, None, False
    p = np.concatenate([x1, np.ones_like(x1[..., :1])], -1) @ hm.T
    z = np.where(np.abs(p[..., 2:]) < 1e-9, 1e-9, p[..., 2:])
    res_h = np.linalg.norm(p[..., :2] / z - x2, axis=-1).astype(np.float32)
    frac_h = float(inl.mean())
    if frac_h >= h_inliers:
        return res_h, None, False
    fm, finl = cv2.findFundamentalMat(s1, s2, cv2.FM_RANSAC, ransac_px, 0.999)
    if fm is None or fm.shape != (3, 3) or float(finl.mean()) < frac_h + f_gain:
        return res_h, None, False
    res_f = np.minimum(res_h, _sampson(fm, x1, x2)).astype(np.float32)
    vote = _edge_fraction(valid & (res_h > 2 * ransac_px) & (res_f <= ransac_px), x2) >= edge
    return res_h, res_f, vote


def _moved(res: np.ndarray, valid: np.ndarray, k: int, abs_px: float, k_sigma: float) -> np.ndarray:
    r = res[valid]
    med = float(np.median(r))
    mad = float(np.median(np.abs(r - med))) * 1.4826
    return valid & (res > max(abs_px * np.sqrt(k), med + k_sigma * mad))


def _ends(ev: np.ndarray, fw: np.ndarray, bw: np.ndarray, has: np.ndarray) -> np.ndarray:
    """A frame seen from one side only (the clip's first and last) cannot tell the object from the
    background it is about to cover or has just uncovered: there the evidence is also capped by its
    neighbour's, brought along the flow."""
    from layercam.geometry import warp

    T = len(ev)
    if T < 3:
        return ev
    if not has[0].all() and has[1].all():
        ev[0] = np.minimum(ev[0], warp(ev[1], fw[0], border="constant"))
    if not has[-1].all() and has[-2].all():
        ev[-1] = np.minimum(ev[-1], warp(ev[-2], bw[-1], border="constant"))
    return ev


def long_range_evidence(fw, bw, fw_ok, bw_ok, offsets=(1, 2, 4, 8), abs_px: float = 0.5, k_sigma: float = 4.0, f_vote: float = 0.5, **pair_kw) -> tuple[dict, float]:
    """Evidence that a pixel moves against the static scene (module docstring): ``({"homography":
    (T, H, W), "epipolar": (T, H, W) | None}, share)``, float32 in [0, 1]; the epipolar evidence only
    when at least ``f_vote`` of the pairs voted for it (``share``)."""
    fw, bw = np.asarray(fw, np.float32), np.asarray(bw, np.float32)
    T = fw.shape[0] + 1
    h, w = fw.shape[1:3]
    kmax = max(offsets)
    acc = np.zeros((2, T, 2, h, w), np.float32)  # model (homography, epipolar), frame, direction
    cnt = np.zeros((T, 2, h, w), np.float32)
    votes = []
    for t in range(T):
        ch = chained_displacements(fw, bw, fw_ok, bw_ok, t, kmax)
        for di, sgn in enumerate((1, -1)):
            for k in offsets:
                if sgn * k not in ch:
                    continue
                d, v = ch[sgn * k]
                if k == 1:
                    v = np.ones_like(v)
                res_h, res_f, vote = pair_residuals(d, v, **pair_kw)
                if res_h is None:
                    continue
                votes.append(vote)
                wk = np.float32(np.sqrt(k))  # a longer pair sees a slow object move farther
                acc[0, t, di] += wk * _moved(res_h, v, k, abs_px, k_sigma)
                acc[1, t, di] += wk * _moved(res_h if res_f is None else res_f, v, k, abs_px, k_sigma)
                cnt[t, di] += wk * v
    share = float(np.mean(votes)) if votes else 0.0
    has = cnt.reshape(T, 2, -1).max(-1) > 0  # (T, 2): a direction with any valid pair
    out = {}
    for name, m in (("homography", 0), ("epipolar", 1)):
        frac = acc[m] / np.maximum(cnt, 1.0)
        ev = np.empty((T, h, w), np.float32)
        for t in range(T):
            ev[t] = np.minimum(2 * frac[t].min(0), frac[t].mean(0)) if has[t].all() else frac[t, 0 if has[t, 0] else 1]
        out[name] = _ends(ev, fw, bw, has)
    if share < f_vote:
        out["epipolar"] = None
    return out, share


def flow_failure(fw, bw, fw_ok, bw_ok, reach: int = 4) -> np.ndarray:
    """Where the flow fails to follow a pixel: for each pixel of each frame, the share of the
    frames 1 .. ``reach`` away on either side that it lands inside of along the chained flow but
    not on a forward-backward consistent track (:func:`chained_displacements`), blurred by 1% of the
    short side; 0 where no track is judged (the last row and column). ``(T, H, W)`` float16 in [0, 1].

    A rigid background, moving or not, is followed for frames (near 0). A running animal's
    legs, head and tail change shape from frame to frame and the flow loses them within a few
    frames (near 1), where the flow's residual against the camera's motion may still be small (the
    flow of a thin, fast part is smoothed into the background's). Occlusion edges fail too, on one
    side: the cue is a weight beside the others, not a mask (:func:`layercam.segment.colour_cut`)."""
    import cv2

    fw, bw = np.asarray(fw, np.float32), np.asarray(bw, np.float32)
    T = fw.shape[0] + 1
    h, w = fw.shape[1:3]
    base = _grid(h, w)
    out = np.zeros((T, h, w), np.float16)  # 2 bytes a pixel, as the background check's residual: long 1080p clips fit
    sigma = 0.01 * min(h, w)
    judged = (base[..., 0] < w - 1) & (base[..., 1] < h - 1)  # the last column and row: no bilinear neighbour to look up
    for t in range(T):
        lost = np.zeros((h, w), np.float32)
        seen = np.zeros((h, w), np.float32)
        for d, v in chained_displacements(fw, bw, fw_ok, bw_ok, t, reach).values():
            p = base + d
            inside = judged & (p[..., 0] >= 0) & (p[..., 0] < w - 1) & (p[..., 1] >= 0) & (p[..., 1] < h - 1)
            lost += inside & ~v
            seen += inside
        out[t] = cv2.GaussianBlur(lost / np.maximum(seen, 1.0), (0, 0), sigma)
    return out


def long_range_moving_share(fw, fw_ok, reach: int = 8, base_px: float = 1.5, rel: float = 0.05) -> np.ndarray:
    """For pairs of frames ``reach`` apart (every ``reach // 2`` frames; fewer when the clip is
    shorter): the share of pixels followed consistently from one to the other whose displacement
    leaves the static scene's model (homography, or the epipolar model where the pair votes for it,
    :func:`pair_residuals`) by more than ``base_px + rel * median displacement``. ``(P,)`` float.
    An object moving 0.1-0.5 px per frame (cows grazing) moves 1-4 px over 8 frames."""
    fw = np.asarray(fw, np.float32)
    T = fw.shape[0] + 1
    k = max(1, min(int(reach), T - 1))
    out = []
    for t in range(0, T - k, max(k // 2, 1)):
        d, v = chained_displacements(fw, None, fw_ok, None, t, k)[k]
        res_h, res_f, vote = pair_residuals(d, v)
        if res_h is None:
            continue
        res = res_f if vote else res_h
        thr = base_px + rel * float(np.median(np.linalg.norm(d[v], axis=-1)))
        out.append(float((v & (res > thr)).mean()))
    return np.asarray(out, np.float32)
