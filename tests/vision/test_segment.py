"""Motion segmentation without a detector (layercam.vision.segment): masks of what moves on its own, and
the foreground layer's bootstrap mapping that follows it."""

from __future__ import annotations

import numpy as np
import pytest

from layercam.vision import flow

from layercam.core import metrics, visibility

from layercam.vision import segment
from layercam.core.config import SegmentConfig
from layercam.core.errors import LayercamError
from layercam.vision.segment.clean import fill_still_frames


def _square_clip(T=6, size=64, side=16, seed=0):
    """Panning textured background + a differently textured square moving on its own."""
    import cv2

    rng = np.random.default_rng(seed)
    big = cv2.GaussianBlur(rng.uniform(0, 1, (size * 2, size * 2, 3)).astype(np.float32), (0, 0), 2.0)
    big = (big - big.min()) / (big.max() - big.min())
    tex = cv2.GaussianBlur(rng.uniform(0, 1, (side, side, 3)).astype(np.float32), (0, 0), 0.8)
    tex = 0.6 + 0.4 * (tex - tex.min()) / (tex.max() - tex.min())
    frames, masks, centres = [], [], []
    for t in range(T):
        bx, by = 10 + 1.0 * t, 8 + 0.5 * t  # camera pan: 1 px, 0.5 px per frame
        m = np.float32([[1, 0, -bx], [0, 1, -by]])
        f = cv2.warpAffine(big, m, (size, size), flags=cv2.INTER_LINEAR)
        x0, y0 = 10 + 3 * t, 12 + 2 * t  # the square: 3 px, 2 px per frame
        f[y0 : y0 + side, x0 : x0 + side] = tex
        mk = np.zeros((size, size), bool)
        mk[y0 : y0 + side, x0 : x0 + side] = True
        frames.append(f)
        masks.append(mk)
        centres.append((x0 + side / 2 - 0.5, y0 + side / 2 - 0.5))
    return np.clip(np.stack(frames), 0, 1), np.stack(masks), np.array(centres)


@pytest.fixture(scope="module")
def square():
    frames, masks, centres = _square_clip()
    fw, bw = flow.compute_flow(frames, "dis_fast", progress=False)
    return {"frames": frames, "masks": masks, "centres": centres, "fw": fw, "bw": bw,
            "fw_ok": flow.flow_consistency(fw, bw), "homs": flow.global_homographies(fw)}


def test_motion_masks_find_the_moving_square(square):
    m, info = segment.motion_masks(square["fw"], square["bw"], cfg=SegmentConfig())
    assert m.shape == square["masks"].shape and m.dtype == np.float32
    assert set(np.unique(m)) <= {0.0, 1.0}
    ious = [metrics.iou(m[t] > 0.5, square["masks"][t]) for t in range(len(m))]
    assert np.mean(ious) > 0.5, ious
    for t in range(len(m)):
        ys, xs = np.nonzero(m[t])
        assert len(xs) > 0, f"frame {t}: nothing found"
        assert np.hypot(xs.mean() - square["centres"][t][0], ys.mean() - square["centres"][t][1]) < 5.0
    assert info["empty_frames"] == 0


def test_foreground_bootstrap_masks_and_object_mapping(square):
    fl = {k: square[k] for k in ("fw", "bw", "fw_ok", "homs")}
    fb = segment.foreground_bootstrap(square["frames"], fl)
    assert fb["computed"] and fb["masks"].shape == square["masks"].shape
    ious = [metrics.iou(fb["masks"][t] > 0.5, square["masks"][t]) for t in range(len(fb["masks"]))]
    assert np.mean(ious) > 0.5, ious
    # the foreground's own motion: the square's centre lands on (nearly) the same atlas point in every frame
    from layercam.core.geometry import normalised_frame_matrix

    n = normalised_frame_matrix(64, 64)
    uv = []
    for t, (cx, cy) in enumerate(square["centres"]):
        p = fb["h0"][t] @ n @ np.array([cx + 0.5, cy + 0.5, 1.0])
        uv.append(p[:2] / p[2])
    uv = np.array(uv)
    spread = np.linalg.norm(uv - uv.mean(0), axis=1).max()
    assert np.abs(uv).max() < 1.0
    # (the square moves 18 px over the clip; through a fixed mapping that would be ~0.5 atlas units)
    assert spread < 0.15, uv
    # given masks win: nothing computed
    given = segment.foreground_bootstrap(square["frames"], fl, square["masks"].astype(np.float32))
    assert not given["computed"] and np.array_equal(given["masks"], square["masks"])


def test_clean_mask_drops_specks_and_fills_holes():
    m = np.zeros((40, 40), bool)
    m[10:30, 10:30] = True
    m[18:22, 18:22] = False  # a hole
    m[2, 2] = m[37, 5] = True  # specks
    c = segment.clean_mask(m)
    assert c[20, 20] and not c[2, 2] and not c[37, 5]
    assert c[10:30, 10:30].mean() > 0.95


def test_clean_mask_keeps_a_split_off_part_within_the_gap():
    """An object a trunk cuts in two keeps both halves where they lie within ``GAP`` times the
    larger half's size (the square root of its area) of each other; a part farther away goes,
    whatever its colours."""
    m = np.zeros((60, 80), bool)
    m[15:45, 5:30] = True  # the larger half: size 27 px, the gap 6.8 px
    m[22:38, 35:47] = True  # the other half, beyond a trunk 5 px wide (the closing does not bridge it)
    m[22:38, 64:72] = True  # a third part, 34 px away
    colour = np.full(m.shape, 3.0)  # the object's colours everywhere
    for c in (segment.clean_mask(m), segment.clean_mask(m, colour=colour)):
        assert c[30, 20] and c[30, 40] and not c[30, 68]
    m[22:38, 35:47] = False
    m[22:38, 38:50] = True  # a trunk 8 px wide: beyond the gap
    assert not segment.clean_mask(m, colour=colour)[30, 44]


def test_clean_mask_with_a_seed_keeps_the_part_that_holds_it():
    """A cut grown from a small mask that also took a larger part apart from it (a flower pot by
    the lens) keeps the part that holds the mask it grew from, not the largest; with no part
    holding it, the largest as before."""
    m = np.zeros((60, 80), bool)
    m[5:55, 40:78] = True  # the larger part
    m[20:34, 5:19] = True  # the part the cut grew from, 21 px away
    seed = np.zeros_like(m)
    seed[24:30, 8:14] = True
    assert segment.clean_mask(m)[45, 60] and not segment.clean_mask(m)[27, 12]
    c = segment.clean_mask(m, seed=seed)
    assert c[22:32, 7:17].all() and not c[5:55, 40:78].any()
    assert np.array_equal(segment.clean_mask(m, seed=np.zeros_like(m)), segment.clean_mask(m))


def test_clean_mask_gives_back_thin_parts_of_the_objects_colours():
    """A 2 px leg under a body: the opening takes it; with the colour ratio it comes back where the
    leg has the object's colours and touches the body, not where its colours are weak, and a thin
    line of strong colour that touches nothing stays out."""
    m = np.zeros((60, 60), bool)
    m[10:30, 10:40] = True  # the body
    m[30:45, 20:22] = True  # a thin leg
    m[50:52, 5:55] = True  # a thin line apart from it
    colour = np.full(m.shape, 4.0)
    assert not segment.clean_mask(m)[40, 20]
    c = segment.clean_mask(m, colour=colour)
    assert c[40, 20] and c[20, 25] and not c[51, 30]
    colour[30:45, 20:22] = 1.0
    assert not segment.clean_mask(m, colour=colour)[40, 20]


def test_clean_mask_at_half_scale_keeps_a_thin_leg_and_the_gap_between_legs():
    """``scale`` (``colour.CLEAN`` in the colour cut): on a 200 px short side the opening is
    2 px and the closing 4 px at 1; at 0.5 (1 px, 2 px) two 3 px legs stay, without any colour,
    and the 5 px gap between them stays open; at 0 neither runs; 1 is the cleaning as before."""
    m = np.zeros((200, 200), bool)
    m[40:80, 40:120] = True  # the body
    m[80:110, 50:53] = True  # a 3 px leg
    m[80:110, 58:61] = True  # another, 5 px apart
    full, half, none = (segment.clean_mask(m, scale=s) for s in (1.0, 0.5, 0.0))
    assert not full[100, 51] and not full[100, 59]  # the opening took the legs
    assert half[100, 51] and half[100, 59] and not half[100, 55]  # kept, and the gap between them open
    assert (none == m).all()  # neither opening nor closing (no holes, one component)
    assert (segment.clean_mask(m) == full).all()


def test_still_object_inherits_neighbour_masks(square):
    fw, bw = square["fw"].copy(), square["bw"].copy()
    # the object's evidence vanishes in frame 5 (as if it stood still): its mask comes from frame 4
    ev_masks = square["masks"].copy()
    ev_masks[5] = False
    out, filled = fill_still_frames(ev_masks, fw, bw, 0.3)
    assert filled == [5]
    assert metrics.iou(out[5], square["masks"][5]) > 0.4


def test_still_frames_inherit_a_whole_object_not_the_partial_mask_beside_them(square):
    """Frames 0-1 lost the object and frame 2 holds only a sliver of it (as where an object starts
    moving, only its moving parts are seen): 0-1 inherit the nearest mask of the object's typical
    size (frame 3's), not frame 2's sliver, which itself is left as it is."""
    fw, bw = square["fw"].copy(), square["bw"].copy()
    ev_masks = square["masks"].copy()
    ev_masks[:2] = False
    sliver = np.zeros_like(ev_masks[2])
    ys, xs = np.nonzero(ev_masks[2])
    sliver[ys, xs] = xs < xs.min() + (xs.max() - xs.min() + 1) * 0.4  # the left 40% of the square
    ev_masks[2] = sliver
    out, filled = fill_still_frames(ev_masks, fw, bw, 0.3)
    assert filled == [0, 1]
    assert (out[2] == sliver).all()
    for t in (0, 1):
        assert metrics.iou(out[t], square["masks"][t]) > 0.4, t  # carried over 3 and 2 frames
        assert out[t].sum() > 2 * sliver.sum()


def test_bad_inputs_raise():
    with pytest.raises(LayercamError):
        segment.motion_masks(np.zeros((2, 8, 8, 2)), np.zeros((3, 8, 8, 2)), cfg=SegmentConfig())
    with pytest.raises(LayercamError):
        segment.motion_masks(np.zeros((0, 8, 8, 2)), np.zeros((0, 8, 8, 2)), cfg=SegmentConfig())


def test_textured_tells_sky_from_texture_at_any_exposure():
    import cv2

    rng = np.random.default_rng(0)
    tex = cv2.GaussianBlur(rng.uniform(0, 1, (64, 64)).astype(np.float32), (0, 0), 1.0)
    f = np.empty((64, 128), np.float32)
    f[:, :64] = 0.2 + 0.6 * (tex - tex.min()) / (tex.max() - tex.min())  # texture
    f[:, 64:] = np.linspace(0.55, 0.75, 64)[:, None]  # a sky's smooth gradient
    frames = np.stack([f, 0.25 * f])[..., None].repeat(3, -1)  # and two stops darker
    got = visibility.textured(frames)
    assert got.shape == (2, 64, 128) and got.dtype == bool
    for t in range(2):
        assert got[t, 8:-8, 8:56].mean() > 0.95 and got[t, 8:-8, 72:-8].mean() < 0.05, t
    assert visibility.textured(frames, threshold=0).all()


def test_flow_in_a_smooth_sky_is_no_evidence(square):
    """Dense flow over a smooth patch is interpolated from its edges: a wrong vector there is not an
    object. A smooth patch beside the square whose flow is off by 3 px: without the frames the
    masks take it (and lose the square: one object per frame), with them only the square."""
    frames = square["frames"].copy()
    sky = np.s_[:, 44:60, 40:62]
    frames[sky] = np.linspace(0.6, 0.7, 22, dtype=np.float32)[None, None, :, None]
    fw, bw = square["fw"].copy(), square["bw"].copy()
    fw[sky + (0,)] += 3.0
    bw[sky + (0,)] -= 3.0
    blind, _ = segment.motion_masks(fw, bw, cfg=SegmentConfig())
    seen, info = segment.motion_masks(fw, bw, cfg=SegmentConfig(), frames=frames)
    assert blind[sky].mean() > 0.3  # the patch taken for an object
    assert seen[sky].mean() < 0.05 and info["untextured"] > 0.05
    ious = [metrics.iou(seen[t] > 0.5, square["masks"][t]) for t in range(len(seen))]
    assert np.mean(ious) > 0.5, ious
    with pytest.raises(LayercamError, match="do not match"):
        segment.motion_masks(fw, bw, cfg=SegmentConfig(), frames=frames[:, :32])


def test_sure_pixels_leave_a_band_around_each_mask_edge():
    masks = np.zeros((2, 40, 40), bool)
    masks[0, 10:30, 10:30] = True  # frame 1: no object at all
    sure = segment.sure_pixels(masks, band=0.1)  # 4 px of 40
    assert sure[0, 20, 20] and sure[0, 2, 2] and sure[0, 20, 36]  # deep inside, far outside
    assert not sure[0, 10, 20] and not sure[0, 29, 20] and not sure[0, 20, 8] and not sure[0, 20,
                    32]  # on and near the edge
    assert sure[1].all()  # nothing to be unsure about
    assert segment.sure_pixels(masks, band=0.0).all()


def _pan_clip(T=8, size=64, seed=0, follow=False):
    """A textured world panning 2 px and 0.5 px a frame; with ``follow``, a textured 24x20 subject
    the camera follows (it keeps its place, bobbing a pixel); and the subject's masks."""
    import cv2

    rng = np.random.default_rng(seed)
    big = cv2.GaussianBlur(rng.uniform(0, 1, (size * 2, size * 3, 3)).astype(np.float32), (0, 0), 2.0)
    big = (big - big.min()) / (big.max() - big.min())
    sq = cv2.GaussianBlur(rng.uniform(0, 1, (24, 20, 3)).astype(np.float32), (0, 0), 0.8)
    sq = 0.6 + 0.4 * (sq - sq.min()) / (sq.max() - sq.min())
    frames, masks = [], []
    for t in range(T):
        f = cv2.warpAffine(big, np.float32([[1, 0, -(10 + 2.0 * t)], [0, 1, -(8 + 0.5 * t)]]), (size, size))
        m = np.zeros((size, size), bool)
        if follow:
            y0 = 20 + t % 2
            f[y0 : y0 + 24, 22:42] = sq
            m[y0 : y0 + 24, 22:42] = True
        frames.append(f)
        masks.append(m)
    return np.clip(np.stack(frames), 0, 1), np.stack(masks)


def test_a_subject_the_camera_follows_is_the_object_not_the_world():
    """The camera follows a subject: it keeps its place while the world flows past. The camera's
    motion is read from the frame's border, so the subject is what moves against it."""
    frames, truth = _pan_clip(follow=True)
    fw, bw = flow.compute_flow(frames, "dis_fast", progress=False)
    masks, info = segment.find_foreground(frames, {"fw": fw, "bw": bw}, SegmentConfig())
    assert masks.shape == truth.shape and masks.dtype == np.float32
    assert np.mean([metrics.iou(m > 0.5, g) for m, g in zip(masks, truth)]) > 0.8
    assert info["verdict"]["found"], info["verdict"]


def test_a_clip_without_an_object_says_so():
    """A world panning with nothing moving on its own: no masks, and the verdict says why."""
    frames, _ = _pan_clip()
    fw, bw = flow.compute_flow(frames, "dis_fast", progress=False)
    fb = segment.foreground_bootstrap(frames, {"fw": fw, "bw": bw})
    v = fb["info"]["verdict"]
    assert fb["computed"] and not v["found"] and "moves" in v["reason"]


def test_the_verdict_rejects_masks_that_jump_or_sit_on_the_background():
    """Masks that land somewhere else in every frame (the flow is still) do not hold together;
    masks that hold together where the evidence is no higher than around them move like the
    background; a square that moves with its evidence is an object."""
    from layercam.vision.segment.verdict import verdict

    T, h, w = 6, 48, 48
    fw = np.zeros((T - 1, h, w, 2), np.float32)
    jump = np.zeros((T, h, w), bool)
    for t in range(T):
        y, x = (t * 17) % 36, (t * 23) % 36
        jump[t, y : y + 10, x : x + 10] = True
    evidence = jump.astype(np.float32)
    v = verdict(jump, evidence, fw)
    assert not v["found"] and "jump" in v["reason"] and v["consistency"] < 0.5
    still = np.zeros((T, h, w), bool)
    still[:, 10:30, 10:30] = True
    v = verdict(still, np.full((T, h, w), 0.3, np.float32), fw)
    assert not v["found"] and "like what surrounds" in v["reason"] and v["contrast"] < 2
    v = verdict(still, still.astype(np.float32), fw)
    assert v["found"] and v["consistency"] == 1.0
    # a thin limb 4 px wide that moves 2 px a frame against a still flow (the flow missed it): a
    # plain IoU of 1/3, but every pixel lies within the tolerance (1 px here) of the other mask or
    # next to it: the same object
    limb = np.zeros((T, h, w), bool)
    for t in range(T):
        limb[t, 10:30, 10 + 2 * (t % 2) : 14 + 2 * (t % 2)] = True
    v = verdict(limb, limb.astype(np.float32), fw)
    assert v["found"] and 0.7 < v["consistency"] < 0.8, v


def test_the_verdict_counts_each_frame_once_not_each_pixel():
    """An object small and moving in its first frames that fills most of its last ones, where the
    camera's fit locks onto it and no motion test sees it (a rider coming at the camera): pooled
    over pixels its evidence reads under the rest's, but each frame is one sighting of it."""
    from layercam.vision.segment.verdict import evidence_contrast, verdict

    T, h, w = 10, 48, 48
    fw = np.zeros((T - 1, h, w, 2), np.float32)
    masks = np.zeros((T, h, w), bool)
    evidence = np.full((T, h, w), 0.05, np.float32)
    for t in range(T):
        if t < T // 2:
            masks[t, 20:26, 20:26] = True
            evidence[t][masks[t]] = 1.0
        else:
            masks[t, 4:44, 4:44] = True
            evidence[t][masks[t]] = 0.0
    pooled = evidence[masks].mean() / evidence[~masks].mean()
    assert pooled < 1.0  # the pixels' count alone would call it the background's motion
    assert abs(evidence_contrast(masks, evidence) - 0.5 / 0.05) < 1e-3
    v = verdict(masks, evidence, fw)
    assert v["found"], v


def test_a_large_clip_is_segmented_at_the_working_size(monkeypatch):
    """Frames larger than ``WORK_SHORT`` on the short side are segmented at that size: the masks
    come back at the frame's size and find the same object."""
    import layercam.vision.segment as seg

    frames, truth = _pan_clip(follow=True)
    fw, bw = flow.compute_flow(frames, "dis_fast", progress=False)
    monkeypatch.setattr(seg, "WORK_SHORT", 32)
    masks, info = seg.find_foreground(frames, {"fw": fw, "bw": bw}, SegmentConfig())
    assert masks.shape == truth.shape and info["working_size"] == [32, 32]
    assert np.mean([metrics.iou(m > 0.5, g) for m, g in zip(masks, truth)]) > 0.7


def test_the_border_ring_reads_the_cameras_motion_under_a_large_subject():
    """Step 1's contract: a subject covering most of the frame's centre moves one way, the world
    another; the homography fitted to the border ring is the world's (the camera's), and a pair's
    residual is small on the world and large on the subject."""
    from layercam.vision.segment.camera import border_homographies, border_ring, pair_residuals

    h, w = 60, 80
    ring = border_ring(h, w)
    assert ring.shape == (h, w) and ring[0].all() and ring[:, 0].all() and not ring[h // 2, w // 2]
    d = np.zeros((h, w, 2), np.float32)
    d[..., 0], d[..., 1] = 2.0, -1.0  # the world pans (2, -1) px
    subject = np.zeros((h, w), bool)
    subject[12:48, 16:64] = True  # 36% of the frame, inside the ring
    d[subject] = (-3.0, 0.5)
    homs = border_homographies(d[None])
    assert homs.shape == (1, 3, 3) and np.allclose(homs[0][:2, 2], (2.0, -1.0), atol=0.05)
    res, epipolar = pair_residuals(d, np.ones((h, w), bool))
    assert res.shape == (h, w) and not epipolar
    assert np.median(res[~subject]) < 0.1 and np.median(res[subject]) > 4.0
    assert pair_residuals(d, np.zeros((h, w), bool)) == (None, False)  # too few valid ring pixels


def test_motion_evidence_is_a_share_high_on_the_moving_square(square):
    """Step 2's contract: ``(T, H, W)`` float32 in [0, 1], high on what moves against the camera,
    low on the panning background; ``offsets`` are the powers of two up to ``reach``."""
    from layercam.vision.segment.evidence import motion_evidence, offsets

    assert offsets(8) == (1, 2, 4, 8) and offsets(5) == (1, 2, 4) and offsets(0) == (1,)
    from layercam.vision.segment.moving import flow_checks

    ev, info = motion_evidence(square["fw"], square["bw"], *flow_checks(square["fw"], square["bw"]),
                               reach=4, k_sigma=SegmentConfig().k_sigma)
    assert ev.shape == square["masks"].shape and ev.dtype == np.float32 and 0 <= ev.min() and ev.max() <= 1
    inside, outside = ev[square["masks"]].mean(), ev[~square["masks"]].mean()
    assert inside > 0.5 and outside < 0.1, (inside, outside)
