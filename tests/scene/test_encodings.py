"""The atlas grid: bilinear lookups as ``grid_sample`` does them, sparse gradients on the fine
levels (a step touches only the cells its batch reads), and runs saved with the per-level grid
layout loading into the tables."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from layercam.scene.encodings import DenseGrid2D, bilinear_corners


def _reference(grid: DenseGrid2D):
    """Each level as a ``(1, F, r, r)`` leaf image, and the encoding computed by ``grid_sample``."""
    imgs = [grid.level_grid(l)[None].detach().clone().requires_grad_() for l in range(len(grid.resolutions))]

    def encode(uv):
        g = uv.view(1, -1, 1, 2)
        return torch.cat([F.grid_sample(i, g, mode="bilinear", padding_mode="border",
                                        align_corners=False)[0, :, :, 0] for i in imgs], 0).t()

    return imgs, encode


@pytest.mark.parametrize("sparse_cells", [1, 200, 10**9])
def test_lookup_and_gradients_match_grid_sample(sparse_cells):
    torch.manual_seed(0)
    grid = DenseGrid2D(4, 3, 20, 3, init_std=1.0, sparse_cells=sparse_cells)
    imgs, encode = _reference(grid)
    uv = (torch.rand(300, 2) * 2.6 - 1.3).requires_grad_()  # beyond [-1, 1]: borders clamp
    out, ref = grid(uv), encode(uv)
    assert torch.allclose(out, ref, atol=1e-6)
    w = torch.randn_like(out)
    g_uv, = torch.autograd.grad((out * w).sum(), uv, retain_graph=True)
    (ref * w).sum().backward()
    assert torch.allclose(g_uv, uv.grad, atol=1e-5)
    (out * w).sum().backward()
    for l, (table, img) in enumerate(zip(grid.levels, imgs)):
        assert table.weight.grad.is_sparse == (table.num_embeddings >= sparse_cells)
        dense = table.weight.grad.to_dense() if table.weight.grad.is_sparse else table.weight.grad
        r = grid.resolutions[l]
        assert torch.allclose(dense.view(r, r, -1).permute(2, 0, 1), img.grad[0], atol=1e-5), l


def test_sparse_gradient_names_only_the_cells_read():
    grid = DenseGrid2D(2, 8, 64, 2, sparse_cells=1000)
    uv = torch.rand(10, 2) * 0.2  # a small patch of the atlas
    grid(uv).sum().backward()
    g = grid.levels[1].weight.grad
    assert g.is_sparse and g._indices().shape[1] == 4 * 10  # 4 corners per lookup, not 64 x 64 cells
    idx, w = bilinear_corners(uv, 64)
    assert set(g.coalesce()._indices()[0].tolist()) == set(idx.flatten().tolist())
    assert torch.allclose(w.sum(1), torch.ones(10))
    assert grid.levels[0].weight.grad.layout == torch.strided  # 8 x 8 = 64 cells: dense


def test_corners_of_nan_and_infinite_coordinates_stay_inside_the_grid():
    uv = torch.tensor([[float("nan"), 0.0], [float("inf"), -float("inf")], [1e30, -1e30]])
    idx, w = bilinear_corners(uv, 5)
    assert int(idx.min()) >= 0 and int(idx.max()) < 25 and torch.isfinite(w).all()


def test_runs_saved_with_one_image_per_level_load_into_the_tables():
    torch.manual_seed(1)
    grid = DenseGrid2D(3, 4, 40, 2, init_std=1.0, sparse_cells=100)
    # the layout written before the tables: grids.<l> of shape (1, F, r, r)
    old = {f"grids.{l}": grid.level_grid(l)[None].detach().clone() for l in range(3)}
    fresh = DenseGrid2D(3, 4, 40, 2, sparse_cells=100)
    fresh.load_state_dict(old)
    uv = torch.rand(50, 2) * 2 - 1
    assert torch.equal(fresh(uv), grid(uv))
    with pytest.raises(RuntimeError):  # a wrong shape is still an error, not silently reshaped
        DenseGrid2D(3, 4, 41, 2).load_state_dict(old)


def test_same_initial_values_as_one_grid_per_level():
    """The tables start from the values the per-level grids were drawn with (same seed, same order)."""
    torch.manual_seed(3)
    grid = DenseGrid2D(2, 4, 8, 3, init_std=0.5)
    torch.manual_seed(3)
    ref = [torch.randn(1, 3, r, r) * 0.5 for r in (4, 8)]
    assert all(torch.equal(grid.level_grid(l), ref[l][0]) for l in range(2))

