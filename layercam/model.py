"""The whole model: layered scene + implicit camera (exposures, optional blur, tone mapper).

Follows nerfstudio's shape: :meth:`ImplicitCameraModel.loss_dict` returns already-weighted loss
terms; the trainer only sums them. Loss weights live in ``self.weights`` so that schedule callbacks
(flow-weight decay, bootstrap) change them without the model knowing about steps.
"""

from __future__ import annotations

import copy
import math

import numpy as np
import torch
from torch import nn

from layercam import losses
from layercam.camera.exposure import ExposureField
from layercam.camera.tone import FixedTone, ToneMapper
from layercam.config import Config
from layercam.scene.layered import LayeredScene
from layercam.spec import ModelSpec


def atlas_pixels(h0: np.ndarray, frame_hw: tuple[int, int]) -> float:
    """How many frame pixels span the atlas's ``[-1, 1]`` side, from the bootstrap mappings
    ``h0 (L, T, 3, 3)``: the largest over layers and frames of 2 / (uv step of one pixel)."""
    h, w = frame_hw
    h0 = np.asarray(h0, dtype=np.float64).reshape(-1, 3, 3)
    p0 = h0 @ np.array([0.0, 0.0, 1.0])
    px = h0 @ np.array([2.0 / w, 0.0, 1.0])
    py = h0 @ np.array([0.0, 2.0 / h, 1.0])
    uv0, uvx, uvy = (p[:, :2] / p[:, 2:] for p in (p0, px, py))
    step = np.minimum(np.linalg.norm(uvx - uv0, axis=1), np.linalg.norm(uvy - uv0, axis=1))
    return float(2.0 / max(step.min(), 1e-6))


def resolve_sizes(cfg: Config, h0: np.ndarray, frame_hw: tuple[int, int], blur: bool = False) -> Config:
    """Sizes derived in code: ``scene.grid_max_res = 0`` means one grid cell per frame pixel at the
    finest level, from the atlas's extent in frame pixels (:func:`atlas_pixels`), within 32..2048:

    * without a blur generator, the power of two at or above that extent (at least one cell per pixel);
    * with one, the extent itself (at most one cell per pixel). The blur generator samples the scene
      between pixels, so a finer grid lets the scene keep sub-pixel content that each image's PSF
      reads on its own, fitting every image without one sharp scene (measured on the 3-image MFME
      stack, 64 px: 1.8 cells per pixel 30.3 dB PSNR-mu with the PSFs collapsed to deltas, 0.9
      cells per pixel 35.3 dB with PSFs near the true discs).
    """
    if cfg.scene.grid_max_res > 0:
        return cfg
    cfg = copy.deepcopy(cfg)
    px = atlas_pixels(h0, frame_hw)
    res = int(round(px)) if blur else 2 ** math.ceil(math.log2(max(px, 2.0)))
    cfg.scene.grid_max_res = int(min(max(res, 32), 2048))
    cfg.scene.grid_min_res = min(cfg.scene.grid_min_res, cfg.scene.grid_max_res)
    return cfg


class ImplicitCameraModel(nn.Module):
    def __init__(self, cfg: Config, spec: ModelSpec, h0: torch.Tensor, log2_dt: np.ndarray, exposure_learn: str = "none", phase=None, init_log2: float = 0.0, frame_hw: tuple[int, int] = (1, 1)):
        super().__init__()
        cfg = resolve_sizes(cfg, h0.detach().cpu().numpy(), frame_hw, blur=spec.blur != "off")
        self.cfg, self.spec = cfg, spec
        self.frame_hw = frame_hw
        self.scene = LayeredScene(cfg.scene, h0, init_log2)
        self.exposure = ExposureField(log2_dt, exposure_learn if spec.exposures == "learned" else "none", phase)
        self.tone = ToneMapper(cfg.tone.width, cfg.tone.depth, cfg.tone.monotone, lut=cfg.tone.lut, init_slope=cfg.tone.init_slope) if spec.tone_mapper == "learned" else FixedTone()
        self.blur = None
        if spec.blur != "off":
            from layercam.camera.blur import BlurGenerator

            self.blur = BlurGenerator(spec.blur_n, spec.max_offset, h0.shape[1], frame_hw, cfg.blur.width, cfg.blur.depth, init_centre_weight=cfg.blur.init_centre_weight, zero_mean_offsets=cfg.blur.zero_mean_offsets, centre_exact=cfg.blur.centre == "on")
        lc = cfg.loss
        self.weights = {
            "color": lc.color,
            "flow": lc.flow if spec.flow_loss else 0.0,
            "white_balance": lc.white_balance if spec.tone_mapper == "learned" else 0.0,
            "gradient": lc.gradient if spec.tone_mapper == "learned" and not cfg.tone.monotone else 0.0,
            "bootstrap": 1.0 if cfg.scene.deformation == "mlp" else 0.0,
            "rigidity": lc.rigidity,
            "sparsity": lc.sparsity if spec.layers > 1 else 0.0,
            "alpha_flow": lc.alpha_flow if spec.layers > 1 and spec.flow_loss else 0.0,
            "alpha_mask": 0.0,
        }

    # -- rendering ---------------------------------------------------------------------------
    def irradiance(self, xy: torch.Tensor, t: torch.Tensor) -> dict:
        """Sharp scene irradiance (camera dropped): dict with ``log2_r (N, 3)`` etc."""
        return self.scene(xy, t)

    def tone_map(self, log2_r: torch.Tensor, log2_dt: torch.Tensor) -> torch.Tensor:
        return self.tone(log2_r + log2_dt)

    def forward(self, xy: torch.Tensor, t: torch.Tensor, blur: bool = True) -> dict:
        """Through the whole camera: ``rgb (N, 3)`` as the camera would record it."""
        out = self.scene(xy, t)
        log2_r = out["log2_r"]
        if self.blur is not None and blur:
            log2_r = self.blur(self.scene, xy, t, out)
        out["log2_r_camera"] = log2_r
        out["rgb"] = self.tone_map(log2_r, self.exposure(t))
        return out

    # -- training ----------------------------------------------------------------------------
    def loss_dict(self, batch: dict) -> dict:
        w = self.weights
        out = self(batch["xy"], batch["t"])
        terms = {"color": w["color"] * losses.color_loss(out["rgb"], batch["rgb"], self.cfg.loss.clipped)}
        if w["flow"] > 0 and "xy_match" in batch:
            m = self.scene.mappings(batch["xy_match"], batch["t_match"])
            terms["flow"] = w["flow"] * sum(
                losses.flow_loss(uv, uvm, ok) for uv, uvm, ok in zip(out["uv"], m["uv"], self._layer_flow_weights(out, batch["match_ok"]))
            )
            if w["alpha_flow"] > 0 and out["alpha"] is not None:
                terms["alpha_flow"] = w["alpha_flow"] * losses.alpha_flow_loss(out["alpha"], m["alpha"], batch["match_ok"])
        if w["white_balance"] > 0:
            zero = torch.zeros(1, 3, device=batch["xy"].device)
            terms["white_balance"] = w["white_balance"] * losses.white_balance_loss(self.tone(zero), self.cfg.tone.c0)
        if w["gradient"] > 0:
            z = torch.rand(256, 3, device=batch["xy"].device) * 40 - 20
            terms["gradient"] = w["gradient"] * losses.gradient_loss(self.tone, z)
        if w["bootstrap"] > 0:
            terms["bootstrap"] = w["bootstrap"] * sum(
                ((uv - d.bootstrap_target(batch["xy"], batch["t"])) ** 2).sum(1).mean()
                for uv, d in zip(out["uv"], self.scene.deformations)
            )
        if out["alpha"] is not None:
            if w["sparsity"] > 0:
                terms["sparsity"] = w["sparsity"] * losses.sparsity_loss(out["alpha"])
            if w["alpha_mask"] > 0 and "mask" in batch:
                terms["alpha_mask"] = w["alpha_mask"] * losses.mask_loss(out["alpha"], batch["mask"])
        if w["rigidity"] > 0 and self.cfg.scene.deformation == "homography" and self.scene.n_layers > 1:
            xy, t = batch["xy"][:1024], batch["t"][:1024]
            terms["rigidity"] = w["rigidity"] * sum(
                losses.rigidity_loss(d, xy, t, 2.0 / max(self.frame_hw)) for d in self.scene.deformations
            )
        if self.blur is not None:
            terms.update({k: v for k, v in self.blur.regularisers().items()})
        return terms

    @staticmethod
    def _layer_flow_weights(out: dict, ok: torch.Tensor) -> list:
        """Each layer's flow term counts where that layer is seen (Kasten et al.): weights
        ``ok * (1 - alpha)`` and ``ok * alpha`` (alpha detached), or ``ok`` for one layer."""
        if out["alpha"] is None:
            return [ok] * len(out["uv"])
        a = out["alpha"].detach().squeeze(-1)
        return [ok.float() * (1 - a), ok.float() * a]

    def param_groups(self, lr: float, grid_lr: float) -> list[dict]:
        grid, dh, expo, blur, other = [], [], [], [], []
        for name, p in self.named_parameters():
            if name.startswith("blur."):
                blur.append(p)
            elif ".enc.grids." in name:
                grid.append(p)
            elif name.endswith(".dh"):
                dh.append(p)
            elif name.startswith("exposure."):
                expo.append(p)
            else:
                other.append(p)
        groups = [{"params": other, "lr": lr, "name": "mlp"}]
        if grid:
            groups.append({"params": grid, "lr": grid_lr, "name": "grid"})
        if dh:
            groups.append({"params": dh, "lr": lr * 0.1, "name": "homography"})
        if expo:
            groups.append({"params": expo, "lr": max(lr, 1e-3) * 2, "name": "exposure"})
        if blur:  # held at their start for the first cfg.blur.warmup of training (the trainer reads "start")
            groups.append({"params": blur, "lr": lr, "name": "blur", "start": float(self.cfg.blur.warmup)})
        return groups
