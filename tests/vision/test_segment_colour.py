"""The finder's colour steps: the graph cut, the clip-wide colour cut and its distance cost."""

from __future__ import annotations

import numpy as np

from layercam.core import metrics
from layercam.vision.segment import colour
from layercam.vision.segment.background import background_refine


_RED, _GREY = [0.8, 0.2, 0.1], [0.55, 0.3, 0.3]


def test_graph_cut_finds_the_least_energy_labelling():
    """``colour.graph_cut`` on 3x4 grids: the labelling it returns costs what the cheapest of all 4096
    labellings costs (unaries and the contrast-sensitive smoothness, brute force)."""
    import itertools

    rng = np.random.default_rng(0)
    for trial in range(5):
        unary = rng.normal(0, 1, (3, 4)).astype(np.float32)
        guide = rng.uniform(0, 1, (3, 4, 3)).astype(np.float32)
        pairs = [((y, x), (y, x + 1)) for y in range(3) for x in range(3)] + [((y, x), (y + 1, x))
                 for y in range(2) for x in range(4)]
        d = np.array([((guide[a] - guide[b]) ** 2).sum() for a, b in pairs])
        wgt = 0.7 * np.exp(-d / (2 * d.mean()))

        def energy(lab):
            e = np.where(lab, np.maximum(-unary, 0), np.maximum(unary, 0)).sum()
            return e + sum(wk for wk, (a, b) in zip(wgt, pairs) if lab[a] != lab[b])

        best = min(energy(np.array(bits, bool).reshape(3, 4)) for bits in itertools.product((0, 1), repeat=12))
        got = colour.graph_cut(unary, guide, 0.7)
        assert got.shape == (3, 4) and got.dtype == bool
        assert energy(got) <= best + 0.05, (trial, energy(got), best)  # capacities are rounded to 1/100


def test_colour_cut_grows_a_half_mask_to_the_object_not_to_its_colours_elsewhere(monkeypatch):
    """Motion masks that hold only the back half of a red object grow to the object by its colours,
    at alternating exposures; a static patch of the same colours that the object runs over stays
    out: it does not differ from the background the neighbours show (without that gate it joins).
    Where the object covers the patch its front half stays out too (red on red: no residual)."""
    import cv2

    T, size, side = 10, 96, 20
    rng = np.random.default_rng(5)
    big = cv2.GaussianBlur(rng.uniform(0, 1, (size * 2, size * 2, 3)).astype(np.float32), (0, 0), 2.0)
    big = (big - big.min()) / (big.max() - big.min())
    big[..., 0] *= 0.3  # a green-blue world...
    tex = cv2.GaussianBlur(rng.uniform(0, 1, (side, side)).astype(np.float32), (0, 0), 1.0)
    red = np.stack([0.8 + 0.15 * tex, 0.15 + 0.1 * tex, 0.1 + 0.1 * tex], -1)
    big[100:120, 45:65] = red  # ...with one patch of the object's colours, static, on its path
    frames, truth = [], []
    for t in range(T):
        f = cv2.warpAffine(big, np.float32([[1, 0, -(10 + t)], [0, 1, -(60 + 0.5 * t)]]), (size, size))
        x0, y0 = 12 + 3 * t, 20 + 2 * t  # the red object, 3 px and 2 px a frame
        f[y0 : y0 + side, x0 : x0 + side] = red
        m = np.zeros((size, size), bool)
        m[y0 : y0 + side, x0 : x0 + side] = True
        frames.append(f)
        truth.append(m)
    frames, truth = np.clip(np.stack(frames), 0, 1), np.stack(truth)
    frames[1::2] = frames[1::2] ** 0.6  # every other frame another exposure through another curve
    homs = np.stack([np.array([[1, 0, -1.0], [0, 1, -0.5], [0, 0, 1]])] * (T - 1))
    half = truth.copy()
    for t in range(T):
        xs = np.nonzero(truth[t].any(0))[0]
        half[t][:, xs[0] + side // 2 :] = False  # the front half missed
    patch = np.zeros_like(truth)
    for t in range(T):
        y, x = 100 - 60 - int(np.ceil(0.5 * t)), 45 - 10 - t
        patch[t, y + 1 : y + 19, max(x + 1, 0) : x + 19] = True  # its inside (sub-pixel pan)
    patch &= ~truth
    kept, rel, _ = background_refine(frames, half.astype(np.float32), homs)
    assert rel.shape == truth.shape and rel.dtype == np.float16
    out = colour.colour_cut(frames, kept, rel)
    assert out.shape == truth.shape and out.dtype == bool
    before = np.mean([metrics.iou(half[t], truth[t]) for t in range(T)])
    after = np.mean([metrics.iou(out[t], truth[t]) for t in range(T)])
    assert before < 0.6 and after > 0.65 and after > before + 0.15, (before, after)
    assert out[patch].mean() < 0.05
    monkeypatch.setattr(colour, "GATE", 1e-6)
    ungated = colour.colour_cut(frames, kept, rel)
    assert ungated[patch].mean() > 0.5
    off = colour.colour_cut(frames, np.zeros_like(truth), rel)  # no mask anywhere: nothing to grow
    assert not off.any()


def _red_object_clip(seed: int, stripe: slice) -> tuple[np.ndarray, np.ndarray]:
    """4 frames 64x96 of a noisy blue-green background and a red 20x20 object moving 2 px a frame
    (rows 22-41, from column 20), with a grey stripe of rows ``stripe`` across it; and its masks."""
    rng = np.random.default_rng(seed)
    T, h, w = 4, 64, 96
    frames = np.empty((T, h, w, 3), np.float32)
    frames[...] = [0.1, 0.5, 0.6]
    frames += rng.uniform(-0.05, 0.05, frames.shape).astype(np.float32)
    masks = np.zeros((T, h, w), bool)
    for t in range(T):
        x0 = 20 + 2 * t
        frames[t, 22:42, x0 : x0 + 20] = _RED
        frames[t, stripe, x0 : x0 + 20] = _GREY
        masks[t, 22:42, x0 : x0 + 20] = True
    return frames, masks


def test_colour_cut_pays_for_distance_from_the_mask(monkeypatch):
    """A post of colours between the object's and the background's, moving (the residual marks
    it), runs from the object to the frame's edges: without the distance cost the cut follows it
    across the frame; with it, the post's far ends stay out and the object stays in."""
    frames, masks = _red_object_clip(2, slice(30, 34))  # the object with a stripe of the post's colour
    post = np.zeros_like(masks)
    for t in range(len(frames)):
        x0 = 20 + 2 * t
        frames[t, :, x0 + 20 : x0 + 26] = _GREY  # the post, touching it
        post[t, :, x0 + 20 : x0 + 26] = True
        frames[t, 4:12, 80:88] = _GREY  # both colours in the background too, far off
        frames[t, 50:58, 80:88] = _RED
    rel = (masks | post).astype(np.float16)
    far = post.copy()
    far[:, 12:52] = False  # the post more than 10 px above or below the object
    paid = colour.colour_cut(frames, masks, rel)  # the default cost, 1 an object size
    monkeypatch.setattr(colour, "DISTANCE", 0.0)
    free = colour.colour_cut(frames, masks, rel)
    assert free[far].mean() > 0.5
    assert paid[far].mean() < 0.2 and paid[masks].mean() > 0.95


def test_carry_lost_carries_the_object_not_the_background_it_overlapped():
    """``clean.carry_lost`` on masks that lost the object (no flow: it keeps its place): the
    frame with the largest mask holds the object and a block of background; the next two hold a
    strip of the object. The first of them is offered the whole carried mask; the second only the
    object (the block is not of the object's colours, so it is not carried on); a frame that did
    not lose the object is offered nothing."""
    from layercam.vision.segment.clean import carry_lost

    T, h, w = 3, 48, 64
    obj = np.zeros((h, w), bool)
    obj[10:30, 10:30] = True
    block = np.zeros((h, w), bool)
    block[10:30, 40:50] = True
    strip = obj & (np.arange(h)[:, None] < 14)
    masks = np.stack([obj | block, strip, strip])
    flow = np.zeros((T - 1, h, w, 2), np.float32)
    likely = np.stack([obj] * T)
    extra = carry_lost(masks, flow, flow, likely)
    assert not extra[0].any()
    assert (extra[1] == ((obj | block) & ~strip)).all()
    assert (extra[2] == (obj & ~strip)).all()
    assert not carry_lost(np.stack([obj, obj, obj]), flow, flow, likely).any()


def test_colour_cut_takes_back_what_a_frame_lost_along_the_flow():
    """The red object moves 2 px a frame and its clean-plate residual is zero everywhere (the
    plate holds it too); the motion masks hold all of it in the last frame and a strip of it in
    the others. Without the flow the cut keeps the strips; with it, each frame gets the object."""
    frames, truth = _red_object_clip(3, slice(0, 0))
    masks = truth.copy()
    masks[:-1, 27:, :] = False  # frames 0-2: the top 5 rows only
    rel = np.zeros(truth.shape, np.float16)
    fw = np.zeros((len(frames) - 1,) + truth.shape[1:] + (2,), np.float32)
    fw[..., 0] = 2.0
    bw = -fw
    iou = lambda m: np.mean([metrics.iou(m[t], truth[t]) for t in range(len(m))])  # noqa: E731
    without = colour.colour_cut(frames, masks, rel)
    carried = colour.colour_cut(frames, masks, rel, fw, bw)
    assert iou(without) < 0.5 < 0.9 < iou(carried), (iou(without), iou(carried))
