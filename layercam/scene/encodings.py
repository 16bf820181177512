"""Input encodings for coordinate fields. Each exposes ``out_dim``.

* :class:`PositionalEncoding` — NeRF's sin/cos features (the paper's atlas uses 7 frequencies).
* :class:`DenseGrid2D` — multi-resolution dense 2D feature grids sampled with ``grid_sample``;
  on 2 CPU cores about 6x faster per step than a hash grid and 20x faster than a 4x512 MLP.
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


class PositionalEncoding(nn.Module):
    def __init__(self, in_dim: int, n_freqs: int, include_input: bool = True):
        super().__init__()
        self.in_dim, self.n_freqs, self.include_input = in_dim, n_freqs, include_input
        self.out_dim = in_dim * (2 * n_freqs + int(include_input)) if n_freqs else in_dim

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return positional_encoding(x, self.n_freqs, self.include_input)


class DenseGrid2D(nn.Module):
    """Multi-resolution dense 2D grids. ``(N, 2)`` in ``[-1, 1]`` -> ``(N, levels * features)``.

    Level ``l`` has resolution ``round(min_res * b^l)`` with ``b`` chosen so that the last level is
    ``max_res``. Sampling is bilinear (``align_corners=False``), borders clamp.
    """

    def __init__(self, levels: int = 6, min_res: int = 16, max_res: int = 256, features: int = 4, init_std: float = 1e-2):
        super().__init__()
        if levels < 1 or min_res < 2 or max_res < min_res:
            raise ValueError("DenseGrid2D: need levels >= 1 and 2 <= min_res <= max_res")
        b = (max_res / min_res) ** (1.0 / max(levels - 1, 1))
        self.resolutions = [int(round(min_res * b**l)) for l in range(levels)]
        self.grids = nn.ParameterList(
            [nn.Parameter(torch.randn(1, features, r, r) * init_std) for r in self.resolutions]
        )
        self.out_dim = levels * features

    def forward(self, uv: torch.Tensor) -> torch.Tensor:
        if uv.ndim != 2 or uv.shape[1] != 2:
            raise ValueError(f"DenseGrid2D expects (N, 2), got {tuple(uv.shape)}")
        g = uv.view(1, -1, 1, 2).to(self.grids[0].dtype)
        feats = [
            F.grid_sample(grid, g, mode="bilinear", padding_mode="border", align_corners=False)[0, :, :, 0]
            for grid in self.grids
        ]
        return torch.cat(feats, dim=0).t()
