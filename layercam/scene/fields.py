"""Scene fields: atlas ``(u,v) -> log2 irradiance``, deformation ``(x,y,t) -> (u,v)``, alpha ``(x,y,t) -> alpha``.

Coordinates: ``xy`` is ``(N, 2)`` in ``[-1, 1]`` (x along the width), ``t`` is ``(N,)`` long frame index.
Atlas coordinates ``uv`` live in ``[-1, 1]^2``.
"""

from __future__ import annotations

import torch
from torch import nn

from layercam.core.config import SceneConfig
from layercam.scene.encodings import SPARSE_CELLS, DenseGrid2D, DenseGrid3D, PositionalEncoding, gather_rows
from layercam.scene.mlp import MLP

LOG2_R_BOUND = 40.0  # guard: |log2 irradiance| never exceeds this (2^40 covers any sensor)

# fixed sizes: no preset changes them (the paper's where it gives one); what a preset may change is
# in layercam.core.config.SceneConfig, and the sizes that follow from the clip in layercam.scene.layered
ATLAS_PE_FREQS = 7        # the atlas's positional encoding of (u, v) (paper: 7)
GRID_MIN_RES = 16         # the coarsest atlas grid level, cells across
GRID_FEATURES = 4         # features per grid cell
DEFORM_PE_FREQS = 4       # the residual / MLP deformation's positional encoding of (x, y, t)
RESIDUAL_SCALE = 0.05     # bound of the residual warp, atlas units
ALPHA_WIDTH, ALPHA_DEPTH = 64, 3  # the alpha MLP
ALPHA_PE_FREQS = 6        # alpha's positional encoding of (x, y, t)
ALPHA_GRID_LEVELS = 4     # alpha's dense (x, y, t) grid levels
ALPHA_GRID_FEATURES = 2


class AtlasField(nn.Module):
    """``uv (N, 2) -> log2 r (N, 3)``. Encoding "grid" (fast: ``cfg.grid_levels`` dense levels from
    ``GRID_MIN_RES`` to ``max_res`` cells across) or "pe" (paper: PE(7) -> 4x512)."""

    def __init__(self, cfg: SceneConfig, max_res: int = 256, init_log2: float = 0.0, batch: int | None = None):
        super().__init__()
        if cfg.encoding == "grid":
            # a level is trained sparsely once it has more cells than a step of ``batch`` samples can
            # touch (4 corners each), and always from SPARSE_CELLS on: a step's cost then grows with the
            # batch, not the grid
            sparse = SPARSE_CELLS if batch is None else min(SPARSE_CELLS, 4 * batch)
            self.enc = DenseGrid2D(cfg.grid_levels, min(GRID_MIN_RES, max_res), max_res,
                                   GRID_FEATURES, sparse_cells=sparse)
        elif cfg.encoding == "pe":
            self.enc = PositionalEncoding(2, ATLAS_PE_FREQS)
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
    per-frame correction ``dh`` and the residual MLP both starting at zero (fast, exact at start),
    ``s = RESIDUAL_SCALE``; no residual MLP without ``residual``; ``still``: neither (``uv = h0_t(xy)``,
    ``dh`` held at zero), for the background of a static camera.
    kind "mlp" (paper): ``uv = tanh(MLP(x, y, t))``, fitted to ``h0`` during the bootstrap steps.
    """

    def __init__(self, cfg: SceneConfig, h0: torch.Tensor, residual: bool = True, still: bool = False):
        super().__init__()
        if h0.ndim != 3 or h0.shape[1:] != (3, 3):
            raise ValueError(f"h0 must be (T, 3, 3), got {tuple(h0.shape)}")
        self.kind = cfg.deformation
        self.n_frames = h0.shape[0]
        self.register_buffer("h0", h0.float().clone())
        if self.kind == "homography":
            self.dh = nn.Parameter(torch.zeros(self.n_frames, 8), requires_grad=not still)  # still: h0 alone
            self.residual_scale = RESIDUAL_SCALE if residual and not still else 0.0
            self.residual = None  # residual_scale = 0: the per-frame homographies only
            if self.residual_scale > 0:
                self.pe = PositionalEncoding(3, DEFORM_PE_FREQS)
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


ALPHA_GRID_MAX = 512  # cells across the alpha grid's finest level at most (T x 512^2 x 2 floats)
ALPHA_GRID_CELLS = 1 << 24  # cells of each alpha grid level at most (64 frames at 512 x 512; a
                            # longer clip's frames share slices)


def alpha_grid_capped(cfg: SceneConfig, n_frames: int, frame_hw: tuple[int, int]) -> bool:
    """Whether ``ALPHA_GRID_CELLS`` shapes the alpha grid of a clip of ``n_frames`` (its finest level,
    :func:`layercam.scene.layered.derived_sizes`, over the frames)."""
    r = int(min(max(frame_hw), ALPHA_GRID_MAX))
    return cfg.alpha_encoding == "grid" and n_frames * r * r > ALPHA_GRID_CELLS


class AlphaField(nn.Module):
    """``(xy, t) -> alpha (N, 1)`` in ``(0, 1)``: foreground opacity of a two-layer scene.

    ``alpha_encoding`` "pe": an MLP of the positional encoding of ``(x, y, t)`` (smooth: with 6
    frequencies it cannot draw thin legs). "grid": the same MLP also reads multi-resolution
    dense ``(x, y, t)`` grids (:class:`DenseGrid3D`, ``ALPHA_GRID_LEVELS`` levels, the finest
    ``res`` cells across and one slice per frame, or per few frames in a clip long enough that the
    level would hold more than ``ALPHA_GRID_CELLS``) that can follow the object's outline.
    """

    def __init__(self, cfg: SceneConfig, n_frames: int, res: int = 64):
        super().__init__()
        self.n_frames = n_frames
        self.pe = PositionalEncoding(3, ALPHA_PE_FREQS)
        self.grid = None
        width = self.pe.out_dim
        if cfg.alpha_encoding == "grid":
            if res < 2:
                raise ValueError(f"the alpha grid needs at least 2 cells across, got {res}")
            self.grid = DenseGrid3D(ALPHA_GRID_LEVELS, res, n_frames, ALPHA_GRID_FEATURES, max_cells=ALPHA_GRID_CELLS)
            width += self.grid.out_dim
        self.net = MLP(width, 1, ALPHA_WIDTH, ALPHA_DEPTH)

    def logits(self, xy: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        xy = xy.float()
        feats = self.pe(torch.cat([xy, _t_norm(t, self.n_frames)], dim=1))
        if self.grid is not None:
            # frame t's slice of the finest level, at (2t + 1) / n_frames - 1 along the grid's t
            feats = torch.cat([feats, self.grid.at_frames(xy, t, self.n_frames).float()], dim=1)
        return self.net(feats).float().clamp(-30, 30)

    def forward(self, xy: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.logits(xy, t))
