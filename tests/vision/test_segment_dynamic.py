"""Dynamic textures: a moving part whose outline keeps its place is not the object."""

from __future__ import annotations

import numpy as np

from layercam.core.config import SegmentConfig
from layercam.vision.segment.clean import mask_parts
from layercam.vision.segment.dynamic import follow, keeps_place, travel
from layercam.vision.segment.moving import motion_masks


def _clip(T=10, h=48, w=80, speed=2.0):
    """A still camera; a stream across the top rows, its texture flowing right at ``speed`` px a
    frame inside a fixed outline; a small square below moving right at the same speed."""
    stream = np.zeros((h, w), bool)
    stream[8:22, 4:76] = True
    fw = np.zeros((T - 1, h, w, 2), np.float32)
    bw = np.zeros_like(fw)
    fw[:, stream, 0] = speed
    bw[:, stream, 0] = -speed
    squares = np.zeros((T, h, w), bool)
    for t in range(T):
        x = 10 + int(round(speed * t))
        squares[t, 33:45, x:x + 14] = True  # over KEEP_FRACTION of the stream: it could be the object
    for t in range(T - 1):
        fw[t, squares[t], 0] = speed
        bw[t, squares[t + 1], 0] = -speed
    homs = np.repeat(np.eye(3)[None], T - 1, 0)
    return fw, bw, homs, stream, squares


def test_travel_is_positive_on_an_object_and_not_on_a_fixed_outline():
    fw, bw, homs, stream, squares = _clip()
    ok = np.ones(fw.shape[:3], bool)
    raw = squares | stream[None]
    moves = travel(raw, fw, bw, ok, ok, homs, 8)
    assert moves.shape == raw.shape and np.abs(moves).max() <= 1
    for t in range(len(raw)):
        assert moves[t][squares[t]].sum() > 0
        assert moves[t][stream].sum() <= 0
    assert not moves[:, ~raw.any(0)].any()


def test_keeps_place_by_a_sign_test_over_the_frames():
    fw, bw, homs, stream, squares = _clip()
    ok = np.ones(fw.shape[:3], bool)
    raw = squares | stream[None]
    moves = travel(raw, fw, bw, ok, ok, homs, 8)
    keeps, p = keeps_place(np.broadcast_to(stream, raw.shape), moves)
    assert keeps and p > 0.5
    keeps, p = keeps_place(squares, moves)
    assert not keeps and p < 0.01
    # four frames cannot reach the test's level whatever they show: taken to travel
    assert keeps_place(np.broadcast_to(stream, (4,) + stream.shape), moves[:4]) == (False, 1.0)


def test_follow_keeps_one_track_where_a_choice_frame_by_frame_would_take_the_stream():
    fw, bw, homs, stream, squares = _clip()
    ok = np.ones(fw.shape[:3], bool)
    raw = squares | stream[None]
    small = squares.copy()
    small[:3] = False
    small[:3, 36:42] = squares[:3, 36:42]  # the object's first frames show a corner of it only
    raw[:3] = small[:3] | stream
    moves = travel(raw, fw, bw, ok, ok, homs, 8)
    moves[:3][:, stream] = 0.1  # there the stream's outline travels a little (parallax, noise)
    for t in range(3):  # so a frame's part of the largest travel is the stream there
        assert moves[t][stream].sum() > moves[t][small[t]].sum() > 0
    followed = follow([mask_parts(m) for m in raw], moves, bw)
    assert followed.shape == raw.shape and not followed[:, stream].any()
    assert not followed[:3].any()  # a corner is not the object: those frames are left to their neighbours
    for t in range(3, len(raw)):
        assert (followed[t] == squares[t]).mean() > 0.99
    assert follow([mask_parts(stream)] * len(raw), moves, bw) is None  # no track travels


def test_motion_masks_take_the_object_not_the_stream_beside_it():
    fw, bw, homs, stream, squares = _clip()
    cfg = SegmentConfig()
    plain, _ = motion_masks(fw, bw, cfg=cfg)
    assert plain[:, stream].mean() > 0.9  # without the camera's motion: the largest moving part
    masks, info = motion_masks(fw, bw, cfg=cfg, homs=homs)
    assert info["travel_p"] > 0.05
    iou = [(m.astype(bool) & s).sum() / (m.astype(bool) | s).sum() for m, s in zip(masks, squares)]
    assert min(iou) > 0.6 and masks[:, stream].mean() < 0.02


def test_a_small_object_beside_a_large_stream_still_counts():
    fw, bw, homs, stream, _ = _clip()
    T = len(fw) + 1
    small = np.zeros((T,) + stream.shape, bool)
    for t in range(T):  # 6 x 8 px: a twentieth of the stream, under KEEP_FRACTION of it
        small[t, 36:42, 10 + 2 * t:18 + 2 * t] = True
    fw[:], bw[:] = 0, 0
    fw[:, stream, 0], bw[:, stream, 0] = 2.0, -2.0
    for t in range(T - 1):
        fw[t, small[t], 0] = 2.0
        bw[t, small[t + 1], 0] = -2.0
    masks, info = motion_masks(fw, bw, cfg=SegmentConfig(), homs=homs)
    assert info["travel_p"] > 0.05 and not masks[:, stream].any()
    assert min(masks[t][small[t]].mean() for t in range(T)) > 0.9


def test_the_masks_follow_one_object_not_the_largest_part_of_each_frame():
    fw, bw, homs, _, squares = _clip(T=16)
    T, h, w = squares.shape
    fw[:], bw[:] = 0, 0
    blob = np.zeros_like(squares)
    for t in range(2, 6):  # a larger thing passes through four frames, far from the object
        blob[t, 4 + 2 * t:22 + 2 * t, 52:70] = True
    for t in range(T - 1):
        fw[t, squares[t], 0] = 2.0
        bw[t, squares[t + 1], 0] = -2.0
        fw[t, blob[t], 1] = 2.0
        bw[t, blob[t + 1], 1] = -2.0
    cfg = SegmentConfig()
    plain, _ = motion_masks(fw, bw, cfg=cfg)
    assert plain[3][blob[3]].mean() > 0.9  # each frame's largest part: the thing passing
    masks, info = motion_masks(fw, bw, cfg=cfg, homs=homs)
    assert info["travel_p"] < 0.05 and not masks[blob].any()
    assert min((m.astype(bool) & s).sum() / (m.astype(bool) | s).sum() for m, s in zip(masks, squares)) > 0.7
