"""Long-range motion evidence (layercam.vision.motion): slow objects add up over frames; parallax of near
background that runs off the frame is explained by the epipolar model, the moving object is not."""

from __future__ import annotations

import numpy as np
import pytest

from layercam.vision import flow, motion

from layercam.core import metrics

from layercam.vision import segment


def _texture(rng, h, w, sigma=1.5):
    import cv2

    t = cv2.GaussianBlur(rng.uniform(0, 1, (h, w, 3)).astype(np.float32), (0, 0), sigma)
    return (t - t.min()) / (t.max() - t.min())


def _clip(T=10, size=64, pan=(1.0, 0.0), band=None, obj_speed=(0.0, 2.0), side=12, seed=0):
    """Far textured background panning by ``pan`` px per frame; optionally a near band (the bottom
    ``band`` rows, another texture) panning 2.5 times as fast in the same direction (parallax of a
    translating camera: it runs off the frame's edges); a textured square moving by ``obj_speed``
    against the far background."""
    import cv2

    rng = np.random.default_rng(seed)
    far = _texture(rng, size * 2, size * 4)
    near = _texture(rng, size, size * 6, 1.0) * 0.5 + 0.4
    sq = _texture(rng, side, side, 0.8) * 0.5 + 0.5
    frames, masks = [], []
    for t in range(T):
        m = np.float32([[1, 0, 5 + pan[0] * t], [0, 1, 5 + pan[1] * t]])
        f = cv2.warpAffine(far, m, (size, size), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
        if band:
            mn = np.float32([[1, 0, 5 + 2.5 * pan[0] * t], [0, 1, 0]])
            f[-band:] = cv2.warpAffine(near, mn, (size, band), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)[:band]
        x0, y0 = 30 + (obj_speed[0] - pan[0]) * t, 8 + (obj_speed[1] - pan[1]) * t
        ms = np.float32([[1, 0, -x0], [0, 1, -y0]])
        obj = cv2.warpAffine(sq, ms, (size, size), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                             borderValue=(-1, -1, -1))
        inside = obj[..., 0] >= 0
        f[inside] = obj[inside]
        frames.append(f)
        masks.append(inside)
    return np.clip(np.stack(frames), 0, 1), np.stack(masks)


def _flows(frames):
    fw, bw = flow.compute_flow(frames, "dis_fast", progress=False)
    return fw, bw, flow.flow_consistency(fw, bw), flow.flow_consistency(bw, fw)


def test_chained_displacements_follow_the_pan():
    frames, _ = _clip(T=6, obj_speed=(0.0, 0.0), side=1)
    fw, bw, fo, bo = _flows(frames)
    ch = motion.chained_displacements(fw, bw, fo, bo, 2, 4)
    assert set(ch) == {1, 2, 3, -1, -2}  # inside the clip only
    d, v = ch[3]
    # content moves left 1 px per frame
    assert v.mean() > 0.5 and np.allclose(np.median(d[v], axis=0), [-3.0, 0.0], atol=0.3)
    d, v = ch[-2]
    assert np.allclose(np.median(d[v], axis=0), [2.0, 0.0], atol=0.3)
    fwd = motion.chained_displacements(fw, None, fo, None, 2, 2)
    assert set(fwd) == {1, 2}


def test_flow_vote_outvotes_a_frame_that_lost_the_object_and_reads_only_consistent_chains():
    """A moving square's masks, one frame's emptied: the vote along the flow brings it back where
    the neighbours, carried along the chained flow, agree; a neighbour counts only where the chain
    is consistent, so with every chain inconsistent a frame keeps its own value."""
    frames, masks = _clip(T=7, obj_speed=(0.0, 3.0), side=14)
    fw, bw, fo, bo = _flows(frames)
    vals = masks.astype(np.float32)
    vals[3] = 0.0
    voted = motion.flow_vote(vals, 3, fw, bw, fo, bo, reach=2)
    assert voted.shape == masks.shape[1:] and voted.dtype == np.float32
    assert metrics.iou(voted > 0.5, masks[3]) > 0.8
    assert metrics.iou(vals[3] > 0.5, masks[3]) == 0.0
    own = motion.flow_vote(vals, 3, fw, bw, np.zeros_like(fo), np.zeros_like(bo), reach=2)
    assert np.array_equal(own, vals[3])
    near = {2: vals[3], 3: vals[3], 4: masks[4].astype(np.float32)}  # any mapping of the frames read
    assert not (motion.flow_vote(near, 3, fw, bw, fo, bo, reach=1) > 0.5).any()  # one of three is no majority
    assert np.abs(motion.flow_vote(near, 3, fw, bw, fo, bo, reach=1)).max() > 0.3


def test_a_slow_object_adds_up_over_frames():
    frames, masks = _clip(T=16, obj_speed=(0.0, 0.5), side=16)  # 0.5 px per frame: DIS reads ~0.3 between neighbours
    fw, bw, fo, bo = _flows(frames)
    iou = {}
    for reach in (1, 8):
        m, _ = segment.motion_masks(fw, bw, fo, bo, cfg=segment.SegmentConfig(reach=reach))
        iou[reach] = np.mean([metrics.iou(a > 0.5, b) for a, b in zip(m, masks)])
    assert iou[8] > 0.45 and iou[1] < 0.1, iou
    share = motion.long_range_moving_share(fw, fo, reach=8)
    assert len(share) >= 2 and (share > 0.02).all(), share
    still, _ = _clip(T=16, obj_speed=(0.0, 0.0))
    fw, _, fo, _ = _flows(still)
    assert (motion.long_range_moving_share(fw, fo, reach=8) < 0.01).all()


def test_the_floor_does_not_grow_with_the_pairs_length():
    """0.3 px per frame: 2.4 px over 8 frames, 1.2 over 4, under the floor in neighbour pairs. The
    flow's precision is a floor for every pair alike (a floor growing as sqrt(k) lost this object)."""
    frames, masks = _clip(T=16, obj_speed=(0.0, 0.3), side=16)
    fw, bw, fo, bo = _flows(frames)
    m, _ = segment.motion_masks(fw, bw, fo, bo, cfg=segment.SegmentConfig(reach=8))
    assert np.mean([metrics.iou(a > 0.5, b) for a, b in zip(m, masks)]) > 0.4


def test_parallax_reaching_the_edge_is_explained_the_object_is_not():
    """A near band along the bottom edge pans 2.5 times as fast as the far background (a
    translating camera): the border shows parallax, the epipolar model explains it, the object
    moving across the epipolar lines stays."""
    frames, masks = _clip(T=10, pan=(1.5, 0.0), band=20, obj_speed=(0.0, 2.0))
    fw, bw, fo, bo = _flows(frames)
    m, info = segment.motion_masks(fw, bw, fo, bo, cfg=segment.SegmentConfig())
    assert info["epipolar_pairs"] >= 0.5
    band = np.zeros(masks.shape[1:], bool)
    band[-20:] = True
    assert m[:, band & ~masks.any(0)].mean() < 0.1
    assert np.mean([metrics.iou(a > 0.5, b) for a, b in zip(m, masks)]) > 0.5


@pytest.mark.parametrize("reach,offsets", [(1, (1,)), (5, (1, 2, 4)), (8, (1, 2, 4, 8))])
def test_motion_offsets(reach, offsets):
    assert segment.motion_offsets(reach) == offsets

