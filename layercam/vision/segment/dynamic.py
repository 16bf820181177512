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
test over the frames. The masks then follow one object over the clip (:func:`follow`): each frame's
parts are linked to the next frame's along the flow into tracks, and the object is the track of the
largest travel where the largest parts keep their place, else the track of the largest area; each
frame keeps its part where that part is large enough to be the object, however small beside the
texture, and a frame without one is left to its neighbours (``clean.fill_still_frames``). One track
for the clip, not one part a frame: a part chosen frame by frame goes to the texture or a screen
wherever the object is small or its outline hardly moves for a few frames.

Shapes: masks ``(T, H, W)`` bool, flows ``(T-1, H, W, 2)``, homographies ``(T-1, 3, 3)`` frame t -> t+1.
"""

from __future__ import annotations

import numpy as np

SIGNIFICANCE = 0.05  # the sign test's level: masks that travel in no more frames than chance keep their place
LINK = 0.5  # parts of neighbouring frames are one track where one, carried along the flow, holds most of the smaller


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
    s = [float(w[m].sum()) for m, w in zip(masks, moves) if m.any()]
    if not s:
        return False, 1.0
    p = _sign_p(s)
    return p >= SIGNIFICANCE and 0.5 ** len(s) < SIGNIFICANCE, p


def _sign_p(sums) -> float:
    """The one-sided sign test's p-value: how often ``sums`` are above 0, against chance."""
    from scipy.stats import binomtest

    return float(binomtest(sum(x > 0 for x in sums), len(sums), 0.5, alternative="greater").pvalue)


def follow(parts: list, score: np.ndarray, bw: np.ndarray) -> np.ndarray | None:
    """The clip's one object, followed along the flow: ``(T, H, W)`` bool, or None where no track of
    parts scores above 0 in more frames than chance. ``parts``: per frame, the motion mask's parts
    before cleaning (:func:`~layercam.vision.segment.clean.mask_parts`: ``(n, labels (H, W), areas)``);
    ``score`` ``(T, H, W)``, what a part scores, summed over its pixels: its :func:`travel` (where
    the largest parts keep their place) or the mask itself (its area); ``bw`` ``(T-1, H, W, 2)`` the
    backward flows (frame t+1's pixels -> t).

    Each frame's parts over ``MIN_AREA`` are linked to the next frame's where one, carried along
    the flow, holds ``LINK`` of the smaller; linked parts form tracks. A track's part in a frame is
    its part of the largest score there (a
    texture beside the object can join its track where the two touch); the track of the largest
    score summed over its parts is the object where they score above 0 in more frames of the clip
    than chance (the sign test of :func:`keeps_place`, every frame counted, those without the track
    as 0). Each frame keeps the track's part, with the parts an occluder split off it
    (:func:`~layercam.vision.segment.clean.keep_object`'s ``seed``), where that part is at least
    ``KEEP_FRACTION`` of the frame's largest or the track's median size (a small object beside a
    large texture still counts; a part under both is a fragment of the object), and is empty
    elsewhere (left to the frames that hold it at its typical size)."""
    from layercam.vision.segment.clean import KEEP_FRACTION, MIN_AREA, keep_object, warp_mask

    T = len(parts)
    h, w = parts[0][1].shape
    big, nodes = [], []  # per frame: the labels of its parts over MIN_AREA; nodes: (frame, label, score)
    for t, (n, lab, areas) in enumerate(parts):
        sums = np.bincount(lab.ravel(), weights=np.asarray(score[t], np.float64).ravel(), minlength=n)
        big.append([i for i in range(1, n) if areas[i - 1] >= MIN_AREA * h * w])
        nodes += [(t, i, float(sums[i])) for i in big[t]]
    index = {(t, i): k for k, (t, i, _) in enumerate(nodes)}
    root = list(range(len(nodes)))

    def find(k: int) -> int:
        while root[k] != k:
            root[k] = root[root[k]]
            k = root[k]
        return k

    for t in range(T - 1):
        (_, lab0, a0), (_, lab1, a1) = parts[t], parts[t + 1]
        for i in big[t]:
            held = np.bincount(lab1[warp_mask(lab0 == i, bw[t]) > 0.5], minlength=len(a1) + 1)
            for j in big[t + 1]:
                if held[j] >= LINK * min(a0[i - 1], a1[j - 1]):
                    root[find(index[(t, i)])] = find(index[(t + 1, j)])
    tracks: dict[int, dict] = {}  # per track, its part of the largest score in each frame it holds
    for k, (t, i, x) in enumerate(nodes):
        frames = tracks.setdefault(find(k), {})
        if t not in frames or x > frames[t][1]:
            frames[t] = (i, x)
    if not tracks:
        return None
    best = max(tracks.values(), key=lambda fr: sum(x for _, x in fr.values()))
    if _sign_p([best[t][1] if t in best else 0.0 for t in range(T)]) >= SIGNIFICANCE:
        return None
    size = {t: parts[t][2][i - 1] for t, (i, _) in best.items()}
    typical = np.median(list(size.values()))
    out = np.zeros((T, h, w), bool)
    for t, (i, _) in best.items():
        _, lab, areas = parts[t]
        if size[t] >= min(KEEP_FRACTION * areas.max(), typical):
            out[t] = keep_object(parts[t], seed=lab == i)
    return out
