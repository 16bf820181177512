"""Step 2: what moves against the camera, followed over several frames.

Each pixel of frame t is followed along the chained flow to frames t +- 1, 2, 4, ... up to
``reach`` (:func:`layercam.vision.motion.chained_displacements`); each such pair's displacements are set
against the camera's motion read from the border (:func:`layercam.vision.segment.camera.pair_residuals`).
A pixel moves in a pair when its residual exceeds the pair's own residual level by ``k_sigma``
robust standard deviations (median + k_sigma * 1.4826 MAD: the pair's measured noise), and
by never less than ``MIN_PX`` (the flow's precision). The floor is the same for every pair: a
chained displacement is set against the camera fitted to that same pair, so what its error adds
over k frames is in the pair's measured noise already. Longer pairs see a slow
object move farther and weigh more (sqrt(k)). The evidence is the share of pairs in which the
pixel moves, the smaller of both directions' (twice) and their mean: a moving object disagrees in
both directions, the background it is about to cover, or has just uncovered, in one only.

Shapes: flows ``(T-1, H, W, 2)``, evidence ``(T, H, W)`` float32 in [0, 1].
"""

from __future__ import annotations

import numpy as np

from layercam.vision.segment.camera import pair_residuals

MIN_PX = 0.5  # the flow's precision on real footage: a residual under this is never motion


def offsets(reach: int) -> tuple[int, ...]:
    """Frame offsets 1, 2, 4, ... up to ``reach`` (at least 1)."""
    return tuple(2**i for i in range(int(np.log2(max(int(reach), 1))) + 1))


def _moved(res: np.ndarray, valid: np.ndarray, k_sigma: float) -> np.ndarray:
    r = res[valid]
    med = float(np.median(r))
    mad = float(np.median(np.abs(r - med))) * 1.4826
    return valid & (res > max(MIN_PX, med + k_sigma * mad))


def _ends(ev: np.ndarray, fw: np.ndarray, bw: np.ndarray, has: np.ndarray) -> np.ndarray:
    """A frame seen from one side only (the clip's first and last) cannot tell the object from the
    background it is about to cover or has just uncovered: there the evidence is also capped by its
    neighbour's, brought along the flow."""
    from layercam.core.geometry import warp

    T = len(ev)
    if T < 3:
        return ev
    if not has[0].all() and has[1].all():
        ev[0] = np.minimum(ev[0], warp(ev[1], fw[0], border="constant"))
    if not has[-1].all() and has[-2].all():
        ev[-1] = np.minimum(ev[-1], warp(ev[-2], bw[-1], border="constant"))
    return ev


def motion_evidence(fw, bw, fw_ok, bw_ok, reach: int, k_sigma: float) -> tuple[np.ndarray, dict]:
    """``(evidence (T, H, W) float32 in [0, 1], info)``: the share of pairs (module docstring) in
    which each pixel moves against the camera; ``info``: the share of pairs whose border needed the
    epipolar model (parallax)."""
    from layercam.vision.motion import chained_displacements

    fw, bw = np.asarray(fw, np.float32), np.asarray(bw, np.float32)
    T = fw.shape[0] + 1
    h, w = fw.shape[1:3]
    acc = np.zeros((T, 2, h, w), np.float32)
    cnt = np.zeros((T, 2, h, w), np.float32)
    epi = []
    for t in range(T):
        ch = chained_displacements(fw, bw, fw_ok, bw_ok, t, max(offsets(reach)))
        for di, sgn in enumerate((1, -1)):
            for k in offsets(reach):
                if sgn * k not in ch:
                    continue
                d, v = ch[sgn * k]
                if k == 1:
                    v = np.ones_like(v)
                res, used = pair_residuals(d, v)
                if res is None:
                    continue
                epi.append(used)
                wk = np.float32(np.sqrt(k))
                acc[t, di] += wk * _moved(res, v, k_sigma)
                cnt[t, di] += wk * v
    has = cnt.reshape(T, 2, -1).max(-1) > 0
    frac = acc / np.maximum(cnt, 1.0)
    ev = np.empty((T, h, w), np.float32)
    for t in range(T):
        ev[t] = np.minimum(2 * frac[t].min(0), frac[t].mean(0)) if has[t].all() else frac[t, 0 if has[t, 0] else 1]
    return _ends(ev, fw, bw, has), {"epipolar_pairs": round(float(np.mean(epi)) if epi else 0.0, 3)}
