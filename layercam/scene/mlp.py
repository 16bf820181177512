"""A plain MLP builder: ReLU inner layers, linear output (activations are the caller's)."""

from __future__ import annotations

import torch
from torch import nn


class MLP(nn.Module):
    """``(N, in_dim) -> (N, out_dim)``: ``depth`` hidden layers of ``width`` with ReLU.

    ``zero_last`` initialises the output layer to zero (a field that starts as "no change").
    """

    def __init__(self, in_dim: int, out_dim: int, width: int, depth: int, zero_last: bool = False):
        super().__init__()
        layers: list[nn.Module] = []
        d = in_dim
        for _ in range(depth):
            layers += [nn.Linear(d, width), nn.ReLU(inplace=True)]
            d = width
        last = nn.Linear(d, out_dim)
        if zero_last:
            nn.init.zeros_(last.weight)
            nn.init.zeros_(last.bias)
        layers.append(last)
        self.net = nn.Sequential(*layers)
        self.last = last

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)
