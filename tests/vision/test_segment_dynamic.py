"""Dynamic textures: a moving part whose outline keeps its place is not the object."""

from __future__ import annotations

import numpy as np

from layercam.core.config import SegmentConfig
from layercam.vision.segment.clean import clean_mask
from layercam.vision.segment.dynamic import keeps_place, travel
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


def test_clean_mask_with_a_weight_keeps_the_part_that_travels():
    fw, bw, homs, stream, squares = _clip()
    ok = np.ones(fw.shape[:3], bool)
    raw = squares | stream[None]
    moves = travel(raw, fw, bw, ok, ok, homs, 8)
    assert (clean_mask(raw[4]) == stream).mean() > 0.97  # the largest part
    kept = clean_mask(raw[4], weight=moves[4])
    assert kept[squares[4]].mean() > 0.9 and not kept[stream].any()
    assert not clean_mask(stream, weight=moves[4]).any()  # nothing travels: nothing is kept


def test_motion_masks_take_the_object_not_the_stream_beside_it():
    fw, bw, homs, stream, squares = _clip()
    cfg = SegmentConfig()
    plain, _ = motion_masks(fw, bw, cfg=cfg)
    assert plain[:, stream].mean() > 0.9  # without the camera's motion: the largest moving part
    masks, info = motion_masks(fw, bw, cfg=cfg, homs=homs)
    assert info["travel_p"] > 0.05
    iou = [(m.astype(bool) & s).sum() / (m.astype(bool) | s).sum() for m, s in zip(masks, squares)]
    assert min(iou) > 0.6 and masks[:, stream].mean() < 0.02
