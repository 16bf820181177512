"""Pixel coordinates as the scene's fields read them: a frame's pixels (:mod:`layercam.core.geometry`'s
convention: centres at integers) as ``(N, 2)`` normalised coordinates in ``[-1, 1]`` over the
frame's edges (``grid_sample(align_corners=False)``)."""

from __future__ import annotations

import torch


def normalise_xy(x: torch.Tensor, y: torch.Tensor, w: int, h: int) -> torch.Tensor:
    """Pixel coordinates (:mod:`layercam.core.geometry`'s convention: centres at integers) -> ``(N, 2)``
    normalised coordinates in ``[-1, 1]`` over the frame's edges."""
    return torch.stack([(x + 0.5) / w * 2 - 1, (y + 0.5) / h * 2 - 1], dim=1)


def pixel_grid(h: int, w: int, device="cpu") -> torch.Tensor:
    """All pixel centres of an ``h x w`` frame, row-major, as ``(h*w, 2)`` normalised coordinates."""
    ys, xs = torch.meshgrid(torch.arange(h, device=device, dtype=torch.float32),
                            torch.arange(w, device=device, dtype=torch.float32), indexing="ij")
    return normalise_xy(xs.flatten(), ys.flatten(), w, h)
