"""The finder's camera model: the border ring's RANSAC homography refitted to the whole frame's inliers (LO-RANSAC)."""

from __future__ import annotations

import numpy as np


def _flow_of(hm: np.ndarray, h: int, w: int) -> np.ndarray:
    from layercam.vision.motion import grid_points, project

    x = grid_points(h, w)
    return (project(hm, x) - x).astype(np.float32)


def test_the_refit_fits_the_whole_frames_background_and_keeps_the_subject_out():
    """The ring sees a zoom only along the border, where a translation explains it within the
    RANSAC threshold; refitted to the whole frame's points the seed explains, the model is the zoom
    (the background inside the frame joins), and a large subject moving against it stays out."""
    from layercam.vision.motion import RANSAC_PX, grid_points, project, refit
    from layercam.vision.segment.camera import pair_residuals

    h, w = 90, 120
    zoom = np.array([[1.01, 0, -0.6], [0, 1.01, -0.45], [0, 0, 1]])  # 1% about the centre
    d = _flow_of(zoom, h, w)
    subject = np.zeros((h, w), bool)
    subject[25:65, 35:85] = True
    d[subject] += (3.0, -2.0)
    x = grid_points(h, w)
    seed = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1]])  # what a ring could settle for: no motion at all
    # the seed explains the background ...
    assert np.linalg.norm(project(seed, x) - (x + d), axis=-1)[~subject].max() < RANSAC_PX
    out = refit(seed, x.reshape(-1, 2), (x + d).reshape(-1, 2))
    assert np.allclose(out, zoom, atol=1e-4)  # ... and the refit recovers the zoom, not the subject's motion
    res, epipolar = pair_residuals(d, np.ones((h, w), bool))
    assert not epipolar and np.median(res[~subject]) < 0.05 and res[subject].min() > 3.0


def test_the_refit_keeps_the_seed_when_too_few_points_agree():
    from layercam.vision.motion import refit

    rng = np.random.default_rng(0)
    a = rng.uniform(0, 100, (50, 2))
    b = a + rng.uniform(5, 10, (50, 2))  # nothing within the threshold of the identity
    assert np.array_equal(refit(np.eye(3), a, b), np.eye(3))
