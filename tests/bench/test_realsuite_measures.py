"""layercam.bench.realsuite.measures: clipped-everywhere pixels, static pixels, flicker, scores."""

from __future__ import annotations

import numpy as np
import pytest

from layercam.bench.realsuite import measures


def test_unseen_needs_every_exposure_clipped_or_dark():
    stack = np.full((2, 4, 4, 3), 0.5, np.float32)
    stack[:, 0, 0] = 1.0  # clipped in both
    stack[0, 0, 1], stack[1, 0, 1] = 1.0, 0.0  # clipped in one, black in the other
    stack[0, 0, 2] = 1.0  # clipped in one, seen in the other
    stack[:, 0, 3] = (0.0, 0.0, 0.004)  # dark in every channel, in both
    stack[:, 1, 0] = (0.97, 0.5, 0.5)  # one channel clipped in both
    u = measures.unseen_mask(stack)
    assert u.shape == (4, 4)
    assert u[0, 0] and u[0, 1] and not u[0, 2] and u[0, 3] and u[1, 0]
    assert u.sum() == 4


def test_static_masks_follow_the_camera_and_leave_out_what_moves():
    """A textured scene panning 2 px per frame with exposures alternating 1 EV, and a dark square
    walking across it: registration finds the pan, the square and its margin are not static."""
    import cv2

    t, h, w = 6, 48, 64
    rng = np.random.default_rng(0)
    scene = cv2.GaussianBlur(rng.uniform(0.15, 0.45, (h, w + 2 * t, 3)).astype(np.float32), (0, 0), 1.5)
    frames = np.stack([scene[:, 2 * i : 2 * i + w] * (2.0 if i % 2 else 1.0) for i in range(t)]).clip(0, 0.95)
    for i in range(t):
        frames[i, 30:40, 4 + 6 * i : 12 + 6 * i] = 0.02
    hom = measures.registration(frames)
    assert np.allclose(hom[:, 0, 2], -2.0, atol=0.3) and np.allclose(hom[:, 1, 2], 0.0, atol=0.3)
    s = measures.static_masks(frames, hom, margin=2)
    assert s.shape == (t - 2, h, w)
    # the square is at x 4..11 in frame 0 and at 20..27 of frame 0's view in frame 2; between them
    # (less the blur and the margin) the background shows in both
    assert not s[0, 30:40, 4:12].any() and not s[0, 30:40, 20:28].any() and s[0, 30:40, 15:17].all()
    assert s[0, 3:20, 5:50].mean() > 0.95  # the background holds still once registered
    assert not s[0, :, :3].any()  # what frame 2 does not see (the pan moves the content left)
    # flicker: a display that steps up by 2 codes and back, seen through the same registration
    disp = np.stack([scene[:, 2 * i : 2 * i + w] + (2 / 255.0 if i == 1 else 0.0) for i in range(t)])
    assert measures.flicker(disp, hom, s[:2]) == pytest.approx(2.0, abs=0.3)  # pairs 0-1 and 1-2
    later = s.copy()
    later[:2] = False
    assert measures.flicker(disp, hom, later) == pytest.approx(0.0, abs=0.3)  # pairs 2-3 and 3-4
    assert np.isnan(measures.flicker(disp, hom, np.zeros_like(s)))


def test_scores_leave_out_a_channel_without_signal():
    rng = np.random.default_rng(1)
    gt = np.exp(rng.normal(0, 1, (16, 16, 3))).astype(np.float32)
    gt[..., 1] = 0.0
    gt[0, 0, 1] = 1.0  # a stray value does not make a channel
    assert measures.scored_channels(gt) == [0, 2]
    pred = gt.copy()
    pred[..., 1] = rng.uniform(0, 1, (16, 16))  # whatever the green, the score is that of R and B
    unseen = np.zeros((16, 16), bool)
    unseen[:4] = True
    pred[:4] *= 3.0
    s = measures.score_hdr(pred, gt, unseen)
    assert s["channels"] == "RB" and s["psnr_mu_recov"] == 100.0 and s["psnr_mu"] < 60
    assert measures.display_hdr(pred, gt)[..., 1].max() == 0.0
    assert measures.error_map(pred, gt).shape == (16, 16)


def test_score_deblur_against_the_input_floor():
    rng = np.random.default_rng(0)
    sharp = rng.random((3, 24, 24, 3)).astype(np.float32)
    blurry = np.clip(sharp + rng.normal(0, 0.05, sharp.shape), 0, 1).astype(np.float32)
    floor = measures.score_deblur(blurry, sharp)["psnr_frames"]
    better = blurry.copy()
    better[:2] = sharp[:2] + 0.01  # frames 0, 1 better, frame 2 as the input
    worse = better.copy()
    worse[2] = np.roll(sharp[2], 5, axis=1)  # frame 2 in the wrong view
    s = measures.score_deblur(better, sharp, floor)
    assert s["gain_db"] > 5 and s["frames_below"] == 0 and abs(s["worst_gain_db"]) < 1e-6
    w = measures.score_deblur(worse, sharp, floor)
    assert w["frames_below"] == 1 and w["worst_gain_db"] < -1 and len(w["psnr_frames"]) == 3


def test_score_deblur_aligned_forgives_a_small_shift_only():
    """``psnr_aligned``: a sharp frame one pixel off the truth's instant scores as sharp; five off
    (outside the 3 px search) does not."""
    import cv2

    rng = np.random.default_rng(1)
    sharp = np.stack([cv2.GaussianBlur(rng.random((40, 48, 3)).astype(np.float32), (0, 0), 1.0) for _ in range(2)])
    near = np.roll(sharp, 1, axis=2)
    far = np.roll(sharp, 5, axis=2)
    s_near, s_far = measures.score_deblur(near, sharp), measures.score_deblur(far, sharp)
    assert s_near["psnr"] < 40 and s_near["psnr_aligned"] > 60
    assert s_far["psnr_aligned"] < 40
