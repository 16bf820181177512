"""Input encodings for coordinate fields. Each exposes ``out_dim``.

* :class:`PositionalEncoding` — NeRF's sin/cos features (the paper's atlas uses 7 frequencies).
* :class:`DenseGrid2D` — multi-resolution dense 2D feature grids with bilinear lookups; a training
  step reads and updates only the cells its batch touches (the fine levels are sparse-gradient
  tables), so its cost does not grow with the grid.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn


def positional_encoding(x: torch.Tensor, n_freqs: int, include_input: bool = True) -> torch.Tensor:
    """``(N, D) -> (N, D * (2 * n_freqs + include_input))`` with frequencies ``2^k * pi``."""
    if x.ndim != 2:
        raise ValueError(f"positional_encoding expects (N, D), got {tuple(x.shape)}")
    if n_freqs == 0:
        return x
    freqs = (2.0 ** torch.arange(n_freqs, device=x.device, dtype=x.dtype)) * math.pi
    xf = x[:, :, None] * freqs  # (N, D, F)
    enc = torch.cat([torch.sin(xf), torch.cos(xf)], dim=-1).flatten(1)
    return torch.cat([x, enc], dim=-1) if include_input else enc


def gather_rows(table: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """``table[idx]`` for a per-frame table ``(T, ...)`` and per-sample long indices ``(N,)``, with a
    deterministic backward on every device. ``table[idx]``'s backward accumulates with atomic adds
    on a multi-threaded CPU (two identical training steps then differ in the last bits, and a
    resumed run drifts from an uninterrupted one), and ``index_select``'s does on CUDA; so the CPU
    takes ``index_select`` (also the fastest there: 31 ms against 42 for ``table[idx]`` and 68 for
    ``F.embedding``, 262144 rows of 9, two threads) and CUDA ``F.embedding``."""
    if idx.device.type == "cpu":
        return table.index_select(0, idx)
    flat = table.reshape(table.shape[0], -1) if table.ndim != 2 else table
    return F.embedding(idx, flat).reshape(idx.shape[0], *table.shape[1:])


class PositionalEncoding(nn.Module):
    def __init__(self, in_dim: int, n_freqs: int, include_input: bool = True):
        super().__init__()
        self.in_dim, self.n_freqs, self.include_input = in_dim, n_freqs, include_input
        self.out_dim = in_dim * (2 * n_freqs + int(include_input)) if n_freqs else in_dim

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return positional_encoding(x, self.n_freqs, self.include_input)


# A level with at least this many cells has sparse gradients: a step reads and updates only the
# cells its batch touches (optimiser: layercam.engine.optim.Adam). Coarser levels are touched almost
# everywhere by every batch and keep a dense gradient, which is cheaper there.
SPARSE_CELLS = 128 * 128


def level_image(table: torch.Tensor, res: int) -> torch.Tensor:
    """A level's table ``(res * res, F)`` (row-major cells, row = v) as the ``(1, F, res, res)``
    image ``grid_sample`` reads: a view, not a copy."""
    return table.view(res, res, -1).permute(2, 0, 1)[None]


def bilinear_corners(uv: torch.Tensor, res: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The 4 cells a bilinear lookup into a ``res x res`` level reads: ``uv (N, 2)`` in ``[-1, 1]``
    -> rows ``idx (N, 4)`` (long, ``row * res + column``) and weights ``w (N, 4)``, the convention
    of ``grid_sample(align_corners=False, padding_mode="border")`` (coordinates clamp to the outer
    cell centres; NaN reads as a border)."""
    x = (((uv.float() + 1.0) * res - 1.0) * 0.5).clamp(0.0, res - 1.0)
    x = torch.nan_to_num(x, nan=0.0)
    x0 = x.floor().clamp(max=res - 2)
    f = x - x0
    i = x0.long()
    base = i[:, 1] * res + i[:, 0]
    idx = torch.stack([base, base + 1, base + res, base + res + 1], 1)
    fx, fy = f[:, 0:1], f[:, 1:2]
    return idx, torch.cat([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], 1)


def _sample(img: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """``grid_sample`` of ``img (1, F, r, r)`` at ``uv (N, 2)`` -> ``(N, F)``."""
    return F.grid_sample(img, uv.view(1, -1, 1, 2), mode="bilinear", padding_mode="border",
                         align_corners=False)[0, :, :, 0].t()


class SparseGridSample(torch.autograd.Function):
    """Bilinear lookup into a level table ``(r * r, F)`` at ``uv (N, 2)`` -> ``(N, F)`` whose
    gradient for the table is sparse: the 4 corner rows of each lookup (``O(N)``, not ``O(r^2)``).
    The gradient for ``uv`` is ``grid_sample``'s, computed without the table's dense one."""

    @staticmethod
    def forward(ctx, table: torch.Tensor, uv: torch.Tensor, res: int) -> torch.Tensor:
        ctx.save_for_backward(table, uv)
        ctx.res = res
        with torch.autocast(uv.device.type, enabled=False):  # lookups in the table's precision
            return _sample(level_image(table, res), uv)

    @staticmethod
    def backward(ctx, grad_out: torch.Tensor):
        with torch.autocast(grad_out.device.type, enabled=False):
            return SparseGridSample._grads(ctx, grad_out.to(ctx.saved_tensors[0].dtype))

    @staticmethod
    def _grads(ctx, grad_out: torch.Tensor):
        table, uv = ctx.saved_tensors
        res = ctx.res
        grad_table = grad_uv = None
        if ctx.needs_input_grad[1]:
            g = torch.ops.aten.grid_sampler_2d_backward(
                grad_out.t()[None, :, :, None], level_image(table, res), uv.view(1, -1, 1, 2), 0, 1,
                False, [False, True]
            )[1]
            grad_uv = g.view(-1, 2).to(uv.dtype)
        if ctx.needs_input_grad[0]:
            idx, w = bilinear_corners(uv, res)
            vals = (w[:, :, None] * grad_out[:, None, :]).reshape(-1, table.shape[1])
            grad_table = torch.sparse_coo_tensor(idx.reshape(1, -1), vals, table.shape, check_invariants=False)
        return grad_table, grad_uv, None


class DenseGrid2D(nn.Module):
    """Multi-resolution dense 2D grids. ``(N, 2)`` in ``[-1, 1]`` -> ``(N, levels * features)``.

    Level ``l`` has resolution ``round(min_res * b^l)`` with ``b`` chosen so that the last level is
    ``max_res``. Sampling is bilinear (``align_corners=False``), borders clamp. Each level is a
    table ``levels.<l>.weight`` of ``r * r`` cells by ``F`` features (an ``nn.Embedding``, so that
    data-parallel training knows which gradients are sparse): levels of at least ``sparse_cells``
    cells get sparse gradients (:class:`SparseGridSample`), so that a training step's cost grows
    with the batch, not with the grid. Runs saved with one ``(1, F, r, r)`` parameter per level
    (``grids.<l>``, before the tables) load into this layout.
    """

    def __init__(self, levels: int = 6, min_res: int = 16, max_res: int = 256, features: int = 4,
                 init_std: float = 1e-2, sparse_cells: int = SPARSE_CELLS):
        super().__init__()
        if levels < 1 or min_res < 2 or max_res < min_res:
            raise ValueError("DenseGrid2D: need levels >= 1 and 2 <= min_res <= max_res")
        b = (max_res / min_res) ** (1.0 / max(levels - 1, 1))
        self.resolutions = [int(round(min_res * b**l)) for l in range(levels)]
        self.features = features
        self.out_dim = levels * features
        self.levels = nn.ModuleList()
        for r in self.resolutions:
            # the values one (1, F, r, r) grid per level, drawn in order, had
            init = (torch.randn(1, features, r, r) * init_std)[0].permute(1, 2, 0).reshape(r * r, features).contiguous()
            self.levels.append(nn.Embedding(r * r, features, sparse=r * r >= sparse_cells, _weight=init))
        self._register_load_state_dict_pre_hook(self._from_level_images)

    def forward(self, uv: torch.Tensor) -> torch.Tensor:
        if uv.ndim != 2 or uv.shape[1] != 2:
            raise ValueError(f"DenseGrid2D expects (N, 2), got {tuple(uv.shape)}")
        uv = uv.to(self.levels[0].weight.dtype)
        feats = [
            SparseGridSample.apply(t.weight, uv, r) if t.sparse else _sample(level_image(t.weight, r), uv)
            for t, r in zip(self.levels, self.resolutions)
        ]
        return torch.cat(feats, 1)

    def level_grid(self, level: int) -> torch.Tensor:
        """Level ``level`` as a ``(F, r, r)`` image (rows = v)."""
        return level_image(self.levels[level].weight, self.resolutions[level])[0]

    def _from_level_images(self, state_dict, prefix, *args) -> None:
        """Runs saved before the tables: ``grids.<l>`` ``(1, F, r, r)`` -> ``levels.<l>.weight``."""
        for l in range(len(self.resolutions)):
            old = state_dict.pop(f"{prefix}grids.{l}", None)
            if old is not None:
                state_dict[f"{prefix}levels.{l}.weight"] = old[0].permute(1, 2, 0).reshape(-1, old.shape[1])


class DenseGrid3D(nn.Module):
    """Multi-resolution dense grids over ``(x, y, t)``. ``(N, 3)`` in ``[-1, 1]`` -> ``(N, levels * features)``.

    Level ``l`` has ``res_l`` cells along x and y (geometric from ``max_res / 2^(levels-1)``, at
    least 4, to ``max_res``) and ``frames_l`` along t (from ``frames / 2^(levels-1)``, at least 2,
    to ``frames``): the coarse levels are shared by neighbouring frames, the finest holds one slice
    per frame. With ``max_cells``, the finest level holds at most that many cells: a long clip's
    levels then have the slices of a clip of ``max_cells / max_res^2`` frames, each shared by
    neighbouring frames (the parameters do not grow with the clip). Trilinear sampling
    (``align_corners=False``: frame ``t``'s slice of the
    finest level sits at ``(2t + 1) / frames - 1``), borders clamp.
    """

    def __init__(self, levels: int, max_res: int, frames: int, features: int = 2,
                 init_std: float = 1e-2, max_cells: int = 0):
        super().__init__()
        if levels < 1 or max_res < 2 or frames < 1:
            raise ValueError("DenseGrid3D: need levels >= 1, max_res >= 2 and frames >= 1")
        if max_cells:  # a long clip: neighbouring frames share slices, the finest level holding at most max_cells cells
            frames = min(frames, max(max_cells // max(max_res, 4) ** 2, 2))
        self.shapes = [(max(frames // 2 ** (levels - 1 - l), min(frames, 2)),
                        max(max_res // 2 ** (levels - 1 - l), 4)) for l in range(levels)]
        self.grids = nn.ParameterList([nn.Parameter(torch.randn(1, features, d, r, r) * init_std)
                                       for d, r in self.shapes])
        self.out_dim = levels * features

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        """A saved grid's slices are the ones it was trained with (a model saved before ``max_cells``
        kept one slice per frame however long the clip): levels take the saved shapes."""
        for i, g in enumerate(self.grids):
            saved = state_dict.get(f"{prefix}grids.{i}")
            if (saved is not None and saved.shape != g.shape and saved.shape[:2] == g.shape[:2]
                and saved.shape[3:] == g.shape[3:]):
                self.grids[i] = nn.Parameter(torch.empty_like(saved, device=g.device))
                self.shapes[i] = (int(saved.shape[2]), int(saved.shape[3]))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def forward(self, xyt: torch.Tensor) -> torch.Tensor:
        if xyt.ndim != 2 or xyt.shape[1] != 3:
            raise ValueError(f"DenseGrid3D expects (N, 3), got {tuple(xyt.shape)}")
        g = xyt.view(1, -1, 1, 1, 3).to(self.grids[0].dtype)
        feats = [F.grid_sample(grid, g, mode="bilinear", padding_mode="border",
                               align_corners=False)[0, :, :, 0, 0] for grid in self.grids]
        return torch.cat(feats, dim=0).t()

    def at_frames(self, xy: torch.Tensor, t: torch.Tensor, frames: int) -> torch.Tensor:
        """:meth:`forward` at ``(x, y, (2 t + 1) / frames - 1)`` for integer frame indices ``t (N,)``
        and ``xy (N, 2)``: ``(N, levels * features)``, the same values and gradients to float
        rounding. Each level's slices are read as one tall 2D image (``d * r`` rows of ``r``): a
        bilinear lookup in the slice a frame falls on, blended with the next slice's where the frame
        falls between two (a coarse level). On the CPU two-dimensional lookups are several times
        faster than ``grid_sample``'s trilinear one, forward and backward."""
        if xy.ndim != 2 or xy.shape[1] != 2 or t.shape != xy.shape[:1]:
            raise ValueError(f"DenseGrid3D.at_frames expects xy (N, 2) and t (N,), got "
                             f"{tuple(xy.shape)}, {tuple(t.shape)}")
        xy = xy.to(self.grids[0].dtype)
        tl = t.long()
        feats = []
        for grid, (d, r) in zip(self.grids, self.shapes):
            # the slice coordinate grid_sample computes, ((2t + 1) d / frames - 1) / 2, clamped ("border")
            z = (((2 * tl + 1) * d - frames).double() / (2 * frames)).clamp(0, d - 1)
            z0 = z.floor()
            w = (z - z0).to(xy.dtype)[:, None]
            row = (((xy[:, 1:] + 1) * r - 1) / 2).clamp(0, r - 1)  # the pixel row within a slice
            img = grid.view(1, grid.shape[1], d * r, r)
            slices = [z0] + ([(z0 + 1).clamp(max=d - 1)] if bool((w > 0).any()) else [])  # a second where between two
            rows = torch.cat([row + z.to(xy.dtype)[:, None] * r for z in slices])  # rows of the tall image
            got = _sample(img, torch.cat([xy[:, :1].repeat(len(slices), 1), (2 * rows + 1) / (d * r) - 1], 1))
            feats.append(torch.lerp(*got.chunk(2), w) if len(slices) == 2 else got)
        return torch.cat(feats, dim=1)
