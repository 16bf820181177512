"""The whole model: layered scene + implicit camera (exposures, optional blur, tone mapper).

Follows nerfstudio's shape: :meth:`ImplicitCameraModel.loss_dict` returns already-weighted loss
terms; the trainer only sums them. The weights are a :class:`LossWeights` in ``model.loss_weights``;
the model returns the schedules that change them during training
(:meth:`ImplicitCameraModel.training_callbacks`: flow-weight decay, bootstrap phase, mask taper),
so it never counts steps itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from layercam.engine import losses
from layercam.camera.exposure import ExposureField
from layercam.camera.tone import FixedTone, ToneMapper
from layercam.engine.resolve import Resolved, as_resolved
from layercam.scene.layered import LayeredScene, derived_sizes

# the loss weights no preset changes: the paper's (lambda_c, lambda_f, lambda_w, lambda_g) and the
# layered atlases' (Kasten et al.: rigidity, sparsity, alpha flow)
COLOR, FLOW, WHITE_BALANCE, GRADIENT = 1.0, 100.0, 1.0, 100.0
FLOW_DECAY_END = 0.5         # the flow term decays linearly to 0 by this share of training
RIGIDITY, SPARSITY, ALPHA_FLOW = 0.01, 0.001, 1.0
MASK_GIVEN, MASK_MOTION = 1.0, 0.0  # share of the alpha-mask weight kept all through training:
                                    # given masks | motion masks
FG_FOLLOW = 1e-3             # two layers: the foreground's log2 irradiance pulled to the
                             # background's where alpha is low
FG_FOLLOW_ROWS = 1024        # ... on a batch's first this many samples
WHITE_POINT = 0.5            # the white-balance target T(0) (paper)


@dataclass
class LossWeights:
    """The weight of each loss term (0: the term is not computed). Set from the constants above,
    ``loss`` settings and the model's components; changed during training by the schedules of
    ``training_callbacks``."""

    color: float = 1.0
    flow: float = 0.0
    white_balance: float = 0.0
    gradient: float = 0.0
    bootstrap: float = 0.0
    rigidity: float = 0.0
    sparsity: float = 0.0
    alpha_flow: float = 0.0
    alpha_mask: float = 0.0
    mask_balance: float = 1.0  # class balance of the alpha-mask term (1: balanced, 0: plain BCE)
    fg_follow: float = 0.0


class ImplicitCameraModel(nn.Module):
    """Scene + camera for one clip, built from resolved settings (:class:`layercam.engine.resolve.Resolved`;
    a config with nothing left ``auto`` is taken as one): the ``model`` section says which components
    exist, the others how they are built.

    ``h0 (L, T, 3, 3)``: each layer's bootstrap mapping; ``log2_dt (T,)`` the given exposures,
    ``exposure_learn``/``phase`` what of them is learned (``layercam.io.Exposures``);
    ``init_log2`` the atlases' starting log2 irradiance; ``frame_hw`` the frames' ``(H, W)``;
    ``sizes`` the sizes derived from the clip (:func:`layercam.scene.layered.derived_sizes`; derived
    here when not given, given when a saved model is rebuilt).
    """

    def __init__(self, resolved: Resolved, h0: torch.Tensor, log2_dt: np.ndarray,
                 exposure_learn: str = "none", phase=None, init_log2: float = 0.0,
                 frame_hw: tuple[int, int] = (1, 1), sizes: dict | None = None):
        super().__init__()
        r = as_resolved(resolved, h0.shape[1], frame_hw)
        cfg = r.settings
        m = cfg.model
        if h0.shape[0] != m.layers:
            raise ValueError(f"model.layers = {m.layers} but h0 holds {h0.shape[0]} layer mappings")
        self.resolved, self.cfg = r, cfg
        self.frame_hw = frame_hw
        self.sizes = dict(sizes) if sizes else derived_sizes(h0.numpy(), frame_hw,
            fine=m.blur == "on" or (r.static and m.layers == 1))
        self._robust = float(cfg.loss.robust)  # the colour error's Cauchy scale (0: the paper's MSE)
        self.scene = LayeredScene(cfg.scene, h0, self.sizes, init_log2, residual=r.residual,
                                  still_background=r.still_background, batch=cfg.train.batch)
        self.exposure = ExposureField(log2_dt, exposure_learn if m.exposures == "learned" else "none", phase)
        learned = m.tone_mapper == "learned"
        self.tone = ToneMapper(cfg.tone.width, cfg.tone.depth, lut=cfg.tone.lut) if learned else FixedTone()
        self.blur = None
        if m.blur == "on":
            from layercam.camera.blur import INIT_CENTRE_WEIGHT, BlurGenerator

            self.blur = BlurGenerator(cfg.blur.n, cfg.blur.max_offset, h0.shape[1], frame_hw,
                                      init_centre_weight=INIT_CENTRE_WEIGHT, zero_mean_offsets=True,
                                      centre_exact=r.blur_centre)
        self.loss_weights = LossWeights(
            color=COLOR,
            flow=FLOW if m.flow_loss else 0.0,
            white_balance=WHITE_BALANCE if learned else 0.0,
            gradient=GRADIENT if learned else 0.0,
            bootstrap=1.0 if cfg.scene.deformation == "mlp" else 0.0,
            rigidity=RIGIDITY,
            sparsity=SPARSITY if m.layers > 1 else 0.0,
            alpha_flow=ALPHA_FLOW if m.layers > 1 and m.flow_loss else 0.0,
            fg_follow=FG_FOLLOW if m.layers > 1 else 0.0,
        )

    def training_callbacks(self, masks: bool = False, given: bool = False) -> list:
        """The schedules of this model's loss weights over ``cfg.train.steps``: the flow term decays
        to 0 by ``FLOW_DECAY_END``, the alpha flow term to the share ``loss.alpha_flow_keep`` of
        its weight (1: it keeps it all through training, as in Kasten et al.); the deformation is
        fitted to its bootstrap mapping for the
        first ``train.bootstrap_steps``; with ``masks`` (``given`` by the user, or from motion
        segmentation) and an alpha field, alpha is fitted to them at first, the weight tapering off
        with the flow's to the share ``MASK_GIVEN`` or ``MASK_MOTION`` of it. The term is
        class-balanced (a small object takes its shape fast); given masks only during the bootstrap
        steps, since balanced all through it keeps a halo around a thin object. Motion masks stay
        balanced: they miss parts of the object, which the halo partly covers."""
        c = self.cfg
        if masks and self.scene.alpha is not None:
            self.loss_weights.alpha_mask = 1.0
        return [losses.FlowDecay(FLOW_DECAY_END),
                losses.FlowDecay(FLOW_DECAY_END, keys=("alpha_flow",),
                                 floor=c.loss.alpha_flow_keep),
                losses.BootstrapPhase(c.train.bootstrap_steps,
                                      keys=("bootstrap", "mask_balance") if given
                                      else ("bootstrap",)),
                losses.MaskTaper(c.train.bootstrap_steps, FLOW_DECAY_END,
                                 MASK_GIVEN if given else MASK_MOTION)]

    # -- rendering ---------------------------------------------------------------------------
    def irradiance(self, xy: torch.Tensor, t: torch.Tensor) -> dict:
        """Sharp scene irradiance (camera dropped): dict with ``log2_r (N, 3)`` etc."""
        return self.scene(xy, t)

    def tone_map(self, log2_r: torch.Tensor, log2_dt: torch.Tensor) -> torch.Tensor:
        return self.tone(log2_r + log2_dt)

    def forward(self, xy: torch.Tensor, t: torch.Tensor, blur: bool = True, held: int = 0) -> dict:
        """Through the whole camera: ``rgb (N, 3)`` as the camera would record it. ``held``: the
        scene's (:class:`layercam.scene.layered.LayeredScene`), ``fg_held`` in the output."""
        if self.blur is not None and blur:
            out, log2_r = self.blur.through(self.scene, xy, t, held=held)
        else:
            out = self.scene(xy, t, held=held)
            log2_r = out["log2_r"]
        out["log2_r_camera"] = log2_r
        out["rgb"] = self.tone_map(log2_r, self.exposure(t))
        return out

    # -- training ----------------------------------------------------------------------------
    def loss_dict(self, batch: dict) -> dict:
        w = self.loss_weights
        # the pixels' rows only: with a blur generator the scene also reads their PSFs' samples after them
        out = self(batch["xy"], batch["t"], held=min(FG_FOLLOW_ROWS, batch["xy"].shape[0]) if w.fg_follow > 0 else 0)
        terms = {"color": w.color * losses.color_loss(out["rgb"], batch["rgb"], robust=self._robust)}
        if w.flow > 0 and "xy_match" in batch:
            m = self.scene.mappings(batch["xy_match"], batch["t_match"])
            terms["flow"] = w.flow * sum(
                losses.flow_loss(uv, uvm, ok) for uv, uvm,
                ok in zip(out["uv"], m["uv"], self._layer_flow_weights(out, batch["match_ok"]))
            )
        if w.alpha_flow > 0 and out["alpha"] is not None and "xy_match" in batch:
            # held after the flow's decay: alpha at the matches only
            match_alpha = m["alpha"] if w.flow > 0 else self.scene.alpha(batch["xy_match"], batch["t_match"])
            terms["alpha_flow"] = w.alpha_flow * losses.alpha_flow_loss(out["alpha"], match_alpha, batch["match_ok"])
        if w.white_balance > 0:
            zero = torch.zeros(1, 3, device=batch["xy"].device)
            terms["white_balance"] = w.white_balance * losses.white_balance_loss(self.tone(zero), WHITE_POINT)
        if w.gradient > 0:
            z = self._probe_z(batch)
            terms["gradient"] = w.gradient * losses.gradient_loss(self.tone, z)
        if w.bootstrap > 0:
            terms["bootstrap"] = w.bootstrap * sum(
                ((uv - d.bootstrap_target(batch["xy"], batch["t"])) ** 2).sum(1).mean()
                for uv, d in zip(out["uv"], self.scene.deformations)
            )
        if out["alpha"] is not None:
            if "fg_held" in out:  # on the first samples, the atlas alone (at its coordinates, held fixed)
                n = out["fg_held"].shape[0]
                terms["fg_follow"] = w.fg_follow * losses.fg_follow_loss(out["fg_held"],
                    out["layer_log2_r"][0][:n], out["alpha"][:n])
            if w.sparsity > 0:
                terms["sparsity"] = w.sparsity * losses.sparsity_loss(out["alpha"])
            if w.alpha_mask > 0 and "mask" in batch:
                terms["alpha_mask"] = w.alpha_mask * losses.mask_loss(out["alpha"], batch["mask"], w.mask_balance)
        if w.rigidity > 0 and self.cfg.scene.deformation == "homography" and self.scene.n_layers > 1:
            xy, t = batch["xy"][:1024], batch["t"][:1024]
            terms["rigidity"] = w.rigidity * sum(
                losses.rigidity_loss(d, xy, t, 2.0 / max(self.frame_hw)) for d in self.scene.deformations
            )
        return terms

    @staticmethod
    def _probe_z(batch: dict) -> torch.Tensor:
        """``(N, 3)`` exposed log irradiance in [-20, 20] where the tone mapper's slope is probed:
        the batch's ``probe`` draws (the sampler's stream: a resumed run probes where an
        uninterrupted one does; the global RNG would not), or evenly spaced midpoints without them."""
        u = batch.get("probe")
        if u is None:
            u = ((torch.arange(256, device=batch["xy"].device, dtype=torch.float32) + 0.5) / 256)[:,
                None].expand(256, 3)
        return u * 40 - 20

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
            elif ".enc.levels." in name or ".grid.grids." in name:  # grid tables
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
        if blur:  # held at their start for the first WARMUP of training (the trainer reads "start")
            from layercam.camera.blur import WARMUP

            groups.append({"params": blur, "lr": lr, "name": "blur", "start": WARMUP})
        return groups
