"""One pixel convention for the project (layercam.core.geometry's docstring): centres at integers."""

import numpy as np
import torch

from layercam.core.geometry import frame_corners, normalised_frame_matrix, pixel_grid, warp
from layercam.scene.coords import normalise_xy
from layercam.vision.scale import pixel_scaling


def test_the_frame_edges_are_the_normalised_square_and_the_centres_agree_with_the_sampler():
    h, w = 6, 10
    n = normalised_frame_matrix(h, w) @ frame_corners(h, w)
    assert np.allclose(n[:2] / n[2:], [[-1, 1, -1, 1], [-1, -1, 1, 1]])
    xx, yy = pixel_grid(h, w)
    p = normalised_frame_matrix(h, w) @ np.stack([xx.ravel(), yy.ravel(), np.ones(h * w)])
    s = normalise_xy(torch.from_numpy(xx.ravel()), torch.from_numpy(yy.ravel()), w, h).numpy()
    assert np.allclose(p[:2].T, s, atol=1e-6)


def test_resizing_keeps_the_frame_edges_and_warp_counts_pixels_as_the_grid_does():
    a = pixel_scaling((12, 20), (6, 10))  # pixels of a 6x10 image -> the same image at 12x20
    c = a @ frame_corners(6, 10)
    assert np.allclose(c, frame_corners(12, 20))
    img = np.arange(20, dtype=np.float32).reshape(4, 5)
    flow = np.zeros((4, 5, 2), np.float32)
    flow[..., 0] = 1.0  # one pixel to the right: img(x + 1)
    assert np.array_equal(warp(img, flow)[:, :-1], img[:, 1:])
