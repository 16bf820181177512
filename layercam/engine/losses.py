"""Loss terms as pure functions. The model weights them and returns ``{name: weighted_term}``; the
schedules of those weights over training (:class:`WeightSchedule`: :class:`FlowDecay`,
:class:`BootstrapPhase`, :class:`MaskTaper`) are trainer callbacks the model returns
(``model.training_callbacks``)."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from layercam.engine.train import Callback, Trainer


def color_loss(pred: torch.Tensor, target: torch.Tensor, robust: float = 0.0) -> torch.Tensor:
    """Colour reconstruction (paper Eq. 9), ``(N, 3)`` each: MSE, or with ``robust`` = c > 0 the
    Cauchy loss ``c^2 ln(1 + (e / c)^2)`` (quadratic for errors well under c, growing as a log past
    it)."""
    err = pred.float() - target.float()
    if robust > 0:  # Cauchy: quadratic for small errors, log-growing past c
        return (robust**2 * torch.log1p((err / robust) ** 2)).mean()
    return (err**2).mean()


def flow_loss(uv: torch.Tensor, uv_match: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Flow consistency (paper Eq. 10): ``||q_p - q_p*||^2`` over pairs marked ``valid (N,)``."""
    d = ((uv - uv_match) ** 2).sum(dim=1)
    v = valid.float()
    return (d * v).sum() / v.sum().clamp_min(1.0)


def white_balance_loss(c_at_zero: torch.Tensor, c0: float = 0.5) -> torch.Tensor:
    """``||T(0) - c0||^2`` (paper Eq. 11): unit irradiance at unit exposure maps to mid-grey."""
    return ((c_at_zero.float() - c0) ** 2).mean()


def gradient_loss(tone, z: torch.Tensor, eps: float = 0.05) -> torch.Tensor:
    """``ReLU(-dT/dz)`` (paper Eq. 12) by a forward difference at samples ``z (N, 3)``."""
    slope = (tone(z + eps) - tone(z)) / eps
    return torch.relu(-slope).mean()


def rigidity_loss(uv_fn, xy: torch.Tensor, t: torch.Tensor, delta: float) -> torch.Tensor:
    """Kasten et al.'s rigidity term: the mapping's local Jacobian should be a similarity.

    Estimated with finite differences of size ``delta`` (normalised frame units); penalises
    ``J^T J`` away from a multiple of the identity (symmetric Dirichlet simplified).
    """
    uv0 = uv_fn(xy, t)
    ux = (uv_fn(xy + torch.tensor([delta, 0.0], device=xy.device), t) - uv0) / delta
    uy = (uv_fn(xy + torch.tensor([0.0, delta], device=xy.device), t) - uv0) / delta
    j = torch.stack([ux, uy], dim=2)  # (N, 2, 2)
    jtj = j.transpose(1, 2) @ j
    s = (jtj[:, 0, 0] + jtj[:, 1, 1]) / 2
    off = jtj - s[:, None, None] * torch.eye(2, device=xy.device)
    return (off**2).sum(dim=(1, 2)).mean() / s.detach().clamp_min(1e-8).pow(2).mean()


def fg_follow_loss(fg_log2: torch.Tensor, bg_log2: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """Where the foreground is not, its irradiance follows the background's: ``mean((1 - alpha) *
    (fg_log2 - bg_log2)^2)``, ``(N, 3)`` log2 irradiance each and ``alpha (N, 1)``, with alpha and the
    background held fixed (only the foreground atlas moves). Without it nothing bounds the foreground
    atlas where alpha is near 0 but ``alpha * r_fg`` in the composite, and it drifts up by stops
    until a sliver of alpha lights the background (docs/measurements.md: 8 stops on the Basler clip)."""
    a = alpha.detach().reshape(-1, 1)
    return ((1.0 - a) * (fg_log2.float() - bg_log2.detach().float()) ** 2).mean()


def sparsity_loss(alpha: torch.Tensor) -> torch.Tensor:
    """Prefer a small foreground: mean alpha."""
    return alpha.float().mean()


def alpha_flow_loss(alpha: torch.Tensor, alpha_match: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Alpha should follow the flow: ``|alpha(p) - alpha(p*)|`` over valid pairs."""
    d = (alpha - alpha_match).abs().squeeze(-1)
    v = valid.float()
    return (d * v).sum() / v.sum().clamp_min(1.0)


def mask_loss(alpha: torch.Tensor, mask: torch.Tensor, balance: float = 1.0,
              max_pos_weight: float = 10.0, keep: torch.Tensor | None = None) -> torch.Tensor:
    """Alpha against masks: binary cross-entropy, ``alpha (N, 1)`` and ``mask (N,)`` in {0, 1}.
    With ``balance`` 1 it is class-balanced: foreground pixels weigh ``n_bg / n_fg`` (at most
    ``max_pos_weight``), so that a small object is not learnt as "all background" first (plain BCE
    on a mask covering 3% of DAVIS libby left alpha at 0 after 100 steps); with 0 it is plain BCE,
    whose alpha > 0.5 is the mask itself (balanced, it is where the field gives the object more than
    1 / (1 + weight) of the odds: a halo around a thin object; ``balance`` in between interpolates
    the weight). ``keep (N,)`` bool: only those pixels count (0 when none is kept)."""
    a = alpha.float().squeeze(-1).clamp(1e-5, 1 - 1e-5)
    m = mask.float()
    k = torch.ones_like(m) if keep is None else keep.float()
    n_fg = (m * k).sum()
    pos_w = ((k.sum() - n_fg) / n_fg.clamp_min(1.0)).clamp(1.0, max_pos_weight).detach()
    w = torch.where(m > 0.5, 1.0 + balance * (pos_w - 1.0), torch.ones_like(m)) * k
    return (w * torch.nn.functional.binary_cross_entropy(a, m, reduction="none")).sum() / w.sum().clamp_min(1e-12)


class WeightSchedule(Callback):
    """Sets the model's loss weights named in ``keys`` to their starting values (read at the first
    step) times :meth:`factor` of the step."""

    keys: tuple = ()

    def factor(self, trainer: Trainer, step: int) -> float:  # pragma: no cover - interface
        raise NotImplementedError

    def on_step(self, trainer, step):
        w = trainer.model.loss_weights
        starts = self.__dict__.setdefault("_starts", {})
        k = self.factor(trainer, step)
        for key in self.keys:
            setattr(w, key, starts.setdefault(key, getattr(w, key)) * k)


@dataclass
class FlowDecay(WeightSchedule):
    """The ``keys`` weights decay linearly from their start to ``floor`` (a share of it) at ``end``
    (a fraction of training): the flow's to 0, the alpha flow term's (its own instance) to
    ``loss.alpha_flow_keep``."""

    end: float
    keys: tuple = ("flow",)
    floor: float = 0.0

    def factor(self, trainer, step):
        frac = step / max(trainer.cfg.steps, 1)
        k = max(0.0, 1.0 - frac / max(self.end, 1e-9)) if self.end > 0 else 1.0
        return self.floor + (1.0 - self.floor) * k


@dataclass
class BootstrapPhase(WeightSchedule):
    """During the first ``steps``, fit the deformation to its bootstrap mapping (and masks to alpha)."""

    steps: int
    keys: tuple = ("bootstrap", "alpha_mask")

    def factor(self, trainer, step):
        return 1.0 if step < self.steps else 0.0


@dataclass
class MaskTaper(WeightSchedule):
    """Alpha against its bootstrap masks: full weight during the first ``steps``, then decaying
    linearly to ``floor`` (a share of the start) at ``end`` (a fraction of training, the flow
    decay's end), instead of stopping at once: on DAVIS libby the alpha field had not yet taken the
    mask's shape after 100 steps."""

    steps: int
    end: float
    floor: float = 0.0
    keys: tuple = ("alpha_mask",)

    def factor(self, trainer, step):
        stop = max(int(self.end * trainer.cfg.steps), self.steps + 1)
        k = 1.0 if step < self.steps else max(0.0, 1.0 - (step - self.steps) / (stop - self.steps))
        return max(k, self.floor)
