"""The layered scene: per layer a deformation and an atlas; an alpha field composites two layers.

Layer 0 is the background, layer 1 (if any) the foreground. Irradiance is composited in the
linear domain, ``r = alpha * r_fg + (1 - alpha) * r_bg``, before the camera model.
"""

from __future__ import annotations

import torch
from torch import nn

import math

import numpy as np

from layercam.scene.fields import ALPHA_GRID_MAX, LOG2_R_BOUND, AlphaField, AtlasField, Deformation

GRID_RES_RANGE = (32, 2048)  # the atlas grid's finest level, cells across, at least / at most


def derived_sizes(h0, frame_hw: tuple[int, int], fine: bool) -> dict:
    """The sizes that follow from the clip: ``grid_max_res``, the finest atlas grid level, from the
    atlas's extent in frame pixels (:func:`layercam.core.geometry.atlas_pixels` of the bootstrap mappings
    ``h0 (L, T, 3, 3)``) within :data:`GRID_RES_RANGE`: the power of two at or above it (at least
    one cell per pixel), or with ``fine`` (a blur generator, or a static one-layer scene) the extent
    itself (at most one cell per pixel: the blur generator samples between pixels, so a finer grid
    let each image's PSF read its own sub-pixel content; on a static scene every frame samples the
    same pixel centres, so a finer grid let each frame keep its own noise); ``alpha_grid_res``, one
    cell per pixel along the frame's longer side, at most :data:`ALPHA_GRID_MAX`."""
    from layercam.core.geometry import atlas_pixels

    return sizes_for_extent(atlas_pixels(np.asarray(h0), frame_hw), frame_hw, fine)


def sizes_for_extent(px: float, frame_hw: tuple[int, int], fine: bool) -> dict:
    """:func:`derived_sizes` of an atlas whose frames span ``px`` frame pixels across."""
    res = int(round(px)) if fine else 2 ** math.ceil(math.log2(max(px, 2.0)))
    lo, hi = GRID_RES_RANGE
    return {"grid_max_res": int(min(max(res, lo), hi)), "alpha_grid_res": int(min(max(frame_hw), ALPHA_GRID_MAX))}


class LayeredScene(nn.Module):
    """``(xy (N,2), t (N,)) -> dict(log2_r (N,3), uv [L x (N,2)], alpha (N,1) | None, layer_log2_r)``.

    ``cfg``: the scene settings; ``h0`` is ``(L, T, 3, 3)``: each layer's bootstrap mapping from
    normalised frame coordinates to its atlas; ``sizes``: :func:`derived_sizes`. ``residual``: the
    deformations' residual warp; ``still_background``: two layers from a static camera, the
    background mapped by its bootstrap homography alone (:class:`layercam.engine.resolve.Resolved`).
    ``init_log2`` sets the atlases' initial log2 irradiance; ``batch``: the samples of a training
    step (which grid levels train sparsely, :class:`layercam.scene.fields.AtlasField`).

    ``held`` (forward): with two layers, the foreground atlas is also read at the first ``held``
    rows' coordinates held fixed (detached), in the same call as the rest, as ``fg_held (held, 3)``:
    what the model's ``fg_follow`` term trains the atlas alone on. One call gives each sparse grid
    level one gradient a step; a second call's would be added to it (a sparse sum, slow on the CPU).
    """

    def __init__(self, cfg, h0: torch.Tensor, sizes: dict, init_log2: float = 0.0,
                 residual: bool = True, still_background: bool = False, batch: int | None = None):
        super().__init__()
        if h0.ndim != 4:
            raise ValueError(f"h0 must be (L, T, 3, 3), got {tuple(h0.shape)}")
        self.n_layers, self.n_frames = h0.shape[0], h0.shape[1]
        still_bg = self.n_layers > 1 and still_background
        self.deformations = nn.ModuleList([Deformation(cfg, h0[i], residual=residual,
                                                       still=i == 0 and still_bg)
                                           for i in range(self.n_layers)])
        self.atlases = nn.ModuleList([AtlasField(cfg, sizes["grid_max_res"], init_log2, batch)
                                      for _ in range(self.n_layers)])
        self.alpha = AlphaField(cfg, self.n_frames, sizes["alpha_grid_res"]) if self.n_layers > 1 else None

    def mappings(self, xy: torch.Tensor, t: torch.Tensor) -> dict:
        """Only the geometry: ``uv`` per layer and ``alpha`` (what the flow losses compare)."""
        return {"uv": [d(xy, t) for d in self.deformations],
                "alpha": self.alpha(xy, t) if self.alpha is not None else None}

    def forward(self, xy: torch.Tensor, t: torch.Tensor, held: int = 0) -> dict:
        if xy.ndim != 2 or xy.shape[1] != 2 or t.shape != xy.shape[:1]:
            raise ValueError(f"LayeredScene expects xy (N,2) and t (N,), got {tuple(xy.shape)}, {tuple(t.shape)}")
        uvs = [d(xy, t) for d in self.deformations]
        if self.alpha is None:
            logs = [a(uv) for a, uv in zip(self.atlases, uvs)]
            return {"log2_r": logs[0], "uv": uvs, "alpha": None, "layer_log2_r": logs}
        n = xy.shape[0]
        fg = self.atlases[1](torch.cat([uvs[1], uvs[1][:held].detach()]) if held else uvs[1])
        logs = [self.atlases[0](uvs[0]), fg[:n]]
        alpha = self.alpha(xy, t)
        # log-sum-exp in base 2 keeps the composite finite for any pair of log irradiances
        stacked = torch.stack([logs[0], logs[1]], 0)  # (2, N, 3)
        w = torch.stack([(1 - alpha).clamp_min(1e-12), alpha.clamp_min(1e-12)], 0)
        log2_r = torch.logsumexp(stacked * 0.6931471805599453 + torch.log(w), dim=0) / 0.6931471805599453
        out = {"log2_r": log2_r.clamp(-LOG2_R_BOUND, LOG2_R_BOUND), "uv": uvs, "alpha": alpha, "layer_log2_r": logs}
        if held:
            out["fg_held"] = fg[n:]
        return out
