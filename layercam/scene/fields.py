"""Scene fields: atlas ``(u,v) -> log2 irradiance``, deformation ``(x,y,t) -> (u,v)``, alpha ``(x,y,t) -> alpha``.

Coordinates: ``xy`` is ``(N, 2)`` in ``[-1, 1]`` (x along the width), ``t`` is ``(N,)`` long frame index.
Atlas coordinates ``uv`` live in ``[-1, 1]^2``.
"""

from __future__ import annotations

import torch
from torch import nn

from layercam.config import SceneConfig
from layercam.scene.encodings import DenseGrid2D, DenseGrid3D, PositionalEncoding, gather_rows
from layercam.scene.mlp import MLP

LOG2_R_BOUND = 40.0  # guard: |log2 irradiance| never exceeds this (2^40 covers any sensor)


class AtlasField(nn.Module):
    """``uv (N, 2) -> log2 r (N, 3)``. Encoding "grid" (fast) or "pe" (paper: PE(7) -> 4x512)."""

    def __init__(self, cfg: SceneConfig, init_log2: float = 0.0):
        super().__init__()
        if cfg.encoding == "grid":
            self.enc = DenseGrid2D(cfg.grid_levels, cfg.grid_min_res, cfg.grid_max_res, cfg.grid_features, sparse_cells=cfg.grid_sparse_cells)
        elif cfg.encoding == "pe":
            self.enc = PositionalEncoding(2, cfg.pe_freqs)
        else:
            raise ValueError(f"unknown atlas encoding {cfg.encoding!r} (grid | pe)")
        self.mlp = MLP(self.enc.out_dim, 3, cfg.atlas_width, cfg.atlas_depth)
        with torch.no_grad():
            self.mlp.last.bias.fill_(init_log2)

    def forward(self, uv: torch.Tensor) -> torch.Tensor:
        out = self.mlp(self.enc(uv.float()))  # half-precision coordinates are promoted
        return out.float().clamp(-LOG2_R_BOUND, LOG2_R_BOUND)


def _t_norm(t: torch.Tensor, n_frames: int) -> torch.Tensor:
    return (t.float() / max(n_frames - 1, 1) * 2.0 - 1.0)[:, None]


def apply_homography(h: torch.Tensor, xy: torch.Tensor) -> torch.Tensor:
    """``h (N, 3, 3)``, ``xy (N, 2)`` -> ``(N, 2)``; the projective divide is guarded away from 0.

    Always float32, also under autocast (in bf16 a mapping would be off by ~2^-8 of the frame)."""
    with torch.autocast(xy.device.type, enabled=False):
        h, xy = h.float(), xy.float()
        p = torch.einsum("nij,nj->ni", h, torch.cat([xy, torch.ones_like(xy[:, :1])], dim=1))
        w = p[:, 2:3]
        w = torch.where(w.abs() < 1e-3, torch.where(w < 0, -1e-3, 1e-3).to(w), w)  # sign(0) would give 0
        return p[:, :2] / w


class Deformation(nn.Module):
    """``(xy, t) -> uv``. Starts from a per-frame bootstrap mapping ``h0 (T, 3, 3)``.

    kind "homography": ``uv = (h0_t + dh_t)(xy) + s * tanh(residual(PE(x, y, t)))`` with the
    per-frame correction ``dh`` and the residual MLP both starting at zero (fast, exact at start);
    no residual MLP when ``s = 0``; ``still``: neither (``uv = h0_t(xy)``, ``dh`` held at zero), for
    the background of a static camera.
    kind "mlp" (paper): ``uv = tanh(MLP(x, y, t))``, fitted to ``h0`` during the bootstrap steps.
    """

    def __init__(self, cfg: SceneConfig, h0: torch.Tensor, still: bool = False):
        super().__init__()
        if h0.ndim != 3 or h0.shape[1:] != (3, 3):
            raise ValueError(f"h0 must be (T, 3, 3), got {tuple(h0.shape)}")
        self.kind = cfg.deformation
        self.n_frames = h0.shape[0]
        self.register_buffer("h0", h0.float().clone())
        if self.kind == "homography":
            self.dh = nn.Parameter(torch.zeros(self.n_frames, 8), requires_grad=not still)  # still: h0 alone
            self.residual_scale = 0.0 if still else cfg.residual_scale
            self.residual = None  # residual_scale = 0: the per-frame homographies only
            if self.residual_scale > 0:
                self.pe = PositionalEncoding(3, cfg.deform_pe_freqs)
                self.residual = MLP(self.pe.out_dim, 2, cfg.deform_width, cfg.deform_depth, zero_last=True)
        elif self.kind == "mlp":
            self.net = MLP(3, 2, cfg.deform_width, cfg.deform_depth)
        else:
            raise ValueError(f"unknown deformation {self.kind!r} (homography | mlp)")

    def bootstrap_target(self, xy: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        return apply_homography(self.h0[t], xy.float())

    def forward(self, xy: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        xy, tn = xy.float(), _t_norm(t, self.n_frames)  # half-precision coordinates are promoted
        if self.kind == "mlp":
            return torch.tanh(self.net(torch.cat([xy, tn], dim=1)).float())
        dh = torch.cat([self.dh, torch.zeros_like(self.dh[:, :1])], dim=1).view(-1, 3, 3)
        uv = apply_homography(gather_rows(self.h0 + dh, t), xy)  # (a deterministic backward: gather_rows)
        if self.residual is None:
            return uv
        res = self.residual(self.pe(torch.cat([xy, tn], dim=1))).float()
        return uv + self.residual_scale * torch.tanh(res)


ALPHA_GRID_CELLS = 1 << 24  # cells of each alpha grid level at most (64 frames at 512 x 512; a longer clip's frames share slices)


def alpha_grid_capped(cfg: SceneConfig, n_frames: int, frame_hw: tuple[int, int]) -> bool:
    """Whether ``ALPHA_GRID_CELLS`` shapes the alpha grid of a clip of ``n_frames`` (its finest level,
    ``alpha_grid_res`` or what :func:`layercam.analyse.resolve_auto` derives, over the frames)."""
    from layercam.analyse import ALPHA_GRID_MAX

    r = cfg.alpha_grid_res or int(min(max(frame_hw), ALPHA_GRID_MAX))
    return cfg.alpha_encoding == "grid" and n_frames * r * r > ALPHA_GRID_CELLS


class AlphaField(nn.Module):
    """``(xy, t) -> alpha (N, 1)`` in ``(0, 1)``: foreground opacity of a two-layer scene.

    ``alpha_encoding`` "pe": an MLP of the positional encoding of ``(x, y, t)`` (smooth: with 6
    frequencies it cannot draw a dog's legs at 282x158, and with the true masks of DAVIS libby held
    all through training its IoU stayed below 0.6). "grid": the same MLP also reads multi-resolution
    dense ``(x, y, t)`` grids (:class:`DenseGrid3D`, ``alpha_grid_levels`` levels, the finest
    ``alpha_grid_res`` cells across and one slice per frame, or per few frames in a clip long
    enough that the level would hold more than ``ALPHA_GRID_CELLS``) that can follow the object's
    outline.
    """

    def __init__(self, cfg: SceneConfig, n_frames: int):
        super().__init__()
        self.n_frames = n_frames
        self.pe = PositionalEncoding(3, cfg.alpha_pe_freqs)
        self.grid = None
        width = self.pe.out_dim
        if cfg.alpha_encoding == "grid":
            if cfg.alpha_grid_res < 2:
                raise ValueError("scene.alpha_grid_res must be resolved (analyse.resolve_auto) before the alpha grid is built")
            self.grid = DenseGrid3D(cfg.alpha_grid_levels, cfg.alpha_grid_res, n_frames, cfg.alpha_grid_features, max_cells=ALPHA_GRID_CELLS)
            width += self.grid.out_dim
        self.net = MLP(width, 1, cfg.alpha_width, cfg.alpha_depth)

    def logits(self, xy: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        xy = xy.float()
        feats = self.pe(torch.cat([xy, _t_norm(t, self.n_frames)], dim=1))
        if self.grid is not None:
            tc = (2.0 * t.float() + 1.0) / self.n_frames - 1.0  # frame t's slice of the finest level
            feats = torch.cat([feats, self.grid(torch.cat([xy, tc[:, None]], dim=1)).float()], dim=1)
        return self.net(feats).float().clamp(-30, 30)

    def forward(self, xy: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.logits(xy, t))


class BackgroundChange(nn.Module):
    """``(xy, t) -> (N, 3)``: a small per-frame change of the background's log2 irradiance, in frame
    coordinates, so that what changes over time without moving with anything (rippling water,
    reflections, shadows, flicker) can stay in the background instead of pulling the foreground's
    alpha onto it. One coarse ``cells x cells`` grid per frame (bilinear, starting at 0); its size
    is penalised (``loss.bg_change``), and being coarse it cannot draw an object.
    """

    def __init__(self, n_frames: int, cells: int):
        super().__init__()
        if cells < 1:
            raise ValueError("BackgroundChange needs at least one cell")
        self.n_frames = n_frames
        self.grid = nn.Parameter(torch.zeros(1, 3, n_frames, cells, cells))

    def forward(self, xy: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        tc = (2.0 * t.float() + 1.0) / self.n_frames - 1.0  # frame t's own slice
        g = torch.cat([xy.float(), tc[:, None]], dim=1).view(1, -1, 1, 1, 3)
        out = torch.nn.functional.grid_sample(self.grid, g, mode="bilinear", padding_mode="border", align_corners=False)
        return out[0, :, :, 0, 0].t()
