"""The layered scene: per layer a deformation and an atlas; an alpha field composites two layers.

Layer 0 is the background, layer 1 (if any) the foreground. Irradiance is composited in the
linear domain, ``r = alpha * r_fg + (1 - alpha) * r_bg``, before the camera model.
"""

from __future__ import annotations

import torch
from torch import nn

from layercam.config import SceneConfig
from layercam.scene.fields import LOG2_R_BOUND, AlphaField, AtlasField, BackgroundChange, Deformation


class LayeredScene(nn.Module):
    """``(xy (N,2), t (N,)) -> dict(log2_r (N,3), uv [L x (N,2)], alpha (N,1) | None, layer_log2_r,
    bg_change (N,3) | None)``; with two layers and ``cfg.bg_change_cells`` the background layer's
    log2 irradiance includes its per-frame change (:class:`BackgroundChange`).

    ``h0`` is ``(L, T, 3, 3)``: each layer's bootstrap mapping from normalised frame coordinates to
    its atlas. ``init_log2`` sets the atlases' initial log2 irradiance.
    """

    def __init__(self, cfg: SceneConfig, h0: torch.Tensor, init_log2: float = 0.0):
        super().__init__()
        if h0.ndim != 4:
            raise ValueError(f"h0 must be (L, T, 3, 3), got {tuple(h0.shape)}")
        self.n_layers, self.n_frames = h0.shape[0], h0.shape[1]
        still_bg = self.n_layers > 1 and cfg.still_background == "on"  # a static camera: the background does not move
        self.deformations = nn.ModuleList([Deformation(cfg, h0[i], still=i == 0 and still_bg) for i in range(self.n_layers)])
        self.atlases = nn.ModuleList([AtlasField(cfg, init_log2) for _ in range(self.n_layers)])
        self.alpha = AlphaField(cfg, self.n_frames) if self.n_layers > 1 else None
        self.bg_change = BackgroundChange(self.n_frames, cfg.bg_change_cells) if self.n_layers > 1 and cfg.bg_change_cells > 0 else None

    def mappings(self, xy: torch.Tensor, t: torch.Tensor) -> dict:
        """Only the geometry: ``uv`` per layer and ``alpha`` (what the flow losses compare)."""
        return {"uv": [d(xy, t) for d in self.deformations], "alpha": self.alpha(xy, t) if self.alpha is not None else None}

    def forward(self, xy: torch.Tensor, t: torch.Tensor) -> dict:
        if xy.ndim != 2 or xy.shape[1] != 2 or t.shape != xy.shape[:1]:
            raise ValueError(f"LayeredScene expects xy (N,2) and t (N,), got {tuple(xy.shape)}, {tuple(t.shape)}")
        uvs = [d(xy, t) for d in self.deformations]
        logs = [a(uv) for a, uv in zip(self.atlases, uvs)]
        if self.alpha is None:
            return {"log2_r": logs[0], "uv": uvs, "alpha": None, "layer_log2_r": logs}
        alpha = self.alpha(xy, t)
        change = None
        if self.bg_change is not None:  # the background as it looks in frame t
            change = self.bg_change(xy, t)
            logs = [logs[0] + change, logs[1]]
        # log-sum-exp in base 2 keeps the composite finite for any pair of log irradiances
        stacked = torch.stack([logs[0], logs[1]], 0)  # (2, N, 3)
        w = torch.stack([(1 - alpha).clamp_min(1e-12), alpha.clamp_min(1e-12)], 0)
        log2_r = torch.logsumexp(stacked * 0.6931471805599453 + torch.log(w), dim=0) / 0.6931471805599453
        return {"log2_r": log2_r.clamp(-LOG2_R_BOUND, LOG2_R_BOUND), "uv": uvs, "alpha": alpha, "layer_log2_r": logs, "bg_change": change}
