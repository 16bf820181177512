"""Dynamic textures: moving parts whose outline keeps its place in the scene.

The flow inside a stream, ripples, smoke or leaves in the wind departs from the camera's motion as
an object's does, so the motion evidence takes them in; what sets an object apart is that its
outline goes where its flow goes. (A screen showing moving pictures is one only where its pictures
move out of its outline as often as into it; where they travel, it passes for an object.) Each pixel
of a frame's motion mask is carried to the frames 1, 2, 4, ... ``reach`` away twice, along its
chained flow and by the camera's homography, and :func:`travel` counts whether the flow's end lies
in that frame's mask and the camera's does not (+1) or the reverse (-1). An object scores above 0 at
its edges in almost every
frame; a dynamic texture scores about 0 (its flow's ends and the camera's both land in it, or leave
it as often one way as the other). :func:`keeps_place` reads the clip's largest parts by a sign
test over the frames: where they travel in no more frames than chance, the finder keeps in each frame
the part whose outline travels most (``clean.clean_mask``'s ``weight``), and a frame where none does
is left to its neighbours (``clean.fill_still_frames``).

Shapes: masks ``(T, H, W)`` bool, flows ``(T-1, H, W, 2)``, homographies ``(T-1, 3, 3)`` frame t -> t+1.
"""

from __future__ import annotations

import numpy as np

SIGNIFICANCE = 0.05  # the sign test's level: masks that travel in no more frames than chance keep their place


def travel(raw: np.ndarray, fw, bw, fw_ok, bw_ok, homs: np.ndarray, reach: int) -> np.ndarray:
    """Per pixel, whether the motion masks ``raw`` (before cleaning) travel with the flow or keep
    their place: ``(T, H, W)`` float32 in [-1, 1], the mean over the frames 1, 2, 4, ... ``reach``
    away of ``raw[t+k]`` at the pixel's end along the chained flow minus ``raw[t+k]`` where the
    camera's homography takes it (0 where the chained flow is not valid; the flows' checks ``fw_ok``,
    ``bw_ok`` ``(T-1, H, W)``)."""
    from layercam.core.geometry import chain_homographies
    from layercam.vision.motion import chained_displacements, grid_points, project
    from layercam.vision.segment.evidence import offsets

    T, h, w = raw.shape
    to0 = chain_homographies(np.asarray(homs, np.float64), 0)
    base = grid_points(h, w)
    out = np.zeros((T, h, w), np.float32)

    def at(t: int, p: np.ndarray) -> np.ndarray:
        x, y = np.rint(p[..., 0]).astype(np.int64), np.rint(p[..., 1]).astype(np.int64)
        ins = (x >= 0) & (x < w) & (y >= 0) & (y < h)
        return np.where(ins, raw[t][np.clip(y, 0, h - 1), np.clip(x, 0, w - 1)], False)

    for t in range(T):
        if not raw[t].any():
            continue
        ch = chained_displacements(fw, bw, fw_ok, bw_ok, t, max(offsets(reach)))
        n = 0
        for k in offsets(reach):
            for s in (k, -k):
                if s not in ch:
                    continue
                d, v = ch[s]
                cam = project(np.linalg.inv(to0[t + s]) @ to0[t], base)
                out[t] += v * (at(t + s, base + d).astype(np.float32) - at(t + s, cam))
                n += 1
        out[t] /= max(n, 1)
    return out


def keeps_place(masks, moves: np.ndarray) -> tuple[bool, float]:
    """Whether the ``masks`` ``(T, H, W)`` keep their place rather than travel with their flow, by a
    one-sided sign test over the frames with a mask: how often the mask's summed :func:`travel`
    ``moves`` is above 0. Returns ``(keeps, p)``: the test's p-value, and True where it is at least
    ``SIGNIFICANCE`` though the frames are enough to reach it (``0.5 ** n < SIGNIFICANCE``; with
    fewer the masks are taken to travel)."""
    from scipy.stats import binomtest

    s = [float(w[m].sum()) for m, w in zip(masks, moves) if m.any()]
    if not s:
        return False, 1.0
    p = float(binomtest(sum(x > 0 for x in s), len(s), 0.5, alternative="greater").pvalue)
    return p >= SIGNIFICANCE and 0.5 ** len(s) < SIGNIFICANCE, p
