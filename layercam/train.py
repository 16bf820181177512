"""One training loop for every task. It knows no model: it sums ``model.loss_dict(batch)``.

Schedules are callbacks (nerfstudio's shape), called before each step with the step index:
:class:`FlowDecay` (the paper's flow weight decaying to 0) and :class:`BootstrapPhase`.
Guards: a non-finite loss or gradient skips the step and halves the learning rate; after
``max_bad_steps`` in a row training stops with a clear error, keeping the last good checkpoint.
Ctrl-C saves a checkpoint; the same command resumes from it.
"""

from __future__ import annotations

import contextlib
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch

from layercam.config import TrainConfig
from layercam.errors import LayercamError


class Callback:
    def on_step(self, trainer: "Trainer", step: int) -> None:  # pragma: no cover - interface
        pass


@dataclass
class FlowDecay(Callback):
    """``lambda_f`` decays linearly from its start to 0 at ``end`` (a fraction of training)."""

    start: float
    end: float
    keys: tuple = ("flow", "alpha_flow")
    starts: dict = field(default_factory=dict)

    def on_step(self, trainer, step):
        frac = step / max(trainer.cfg.steps, 1)
        k = max(0.0, 1.0 - frac / max(self.end, 1e-9)) if self.end > 0 else 1.0
        for key in self.keys:
            base = self.starts.setdefault(key, trainer.model.weights.get(key, 0.0))
            trainer.model.weights[key] = base * k


@dataclass
class BootstrapPhase(Callback):
    """During the first ``steps``, fit the deformation to its bootstrap mapping (and masks to alpha)."""

    steps: int
    keys: tuple = ("bootstrap", "alpha_mask")
    starts: dict = field(default_factory=dict)

    def on_step(self, trainer, step):
        for key in self.keys:
            base = self.starts.setdefault(key, trainer.model.weights.get(key, 0.0))
            trainer.model.weights[key] = base if step < self.steps else 0.0


@dataclass
class TrainResult:
    steps: int
    seconds: float
    history: list
    final: dict
    bad_steps: int
    resumed_from: int


class Trainer:
    def __init__(self, model, sampler, cfg: TrainConfig, ckpt_path: Path | None = None, callbacks=(), progress: bool = True, desc: str = "train"):
        self.model, self.sampler, self.cfg = model, sampler, cfg
        self.ckpt_path = Path(ckpt_path) if ckpt_path else None
        self.callbacks = list(callbacks)
        self.progress, self.desc = progress, desc
        self.opt = torch.optim.Adam(model.param_groups(cfg.lr, cfg.grid_lr), betas=(0.9, 0.99), eps=1e-12 if False else 1e-15)
        self.base_lrs = [g["lr"] for g in self.opt.param_groups]
        self.lr_scale = 1.0
        self.step = 0
        self.history: list = []
        self.bad_total = 0

    # -- checkpoints -------------------------------------------------------------------------
    def state(self) -> dict:
        return {
            "model": self.model.state_dict(),
            "opt": self.opt.state_dict(),
            "step": self.step,
            "history": self.history,
            "lr_scale": self.lr_scale,
            "sampler": self.sampler.state_dict(),
            "bad_total": self.bad_total,
        }

    def save(self) -> None:
        if self.ckpt_path is None:
            return
        tmp = self.ckpt_path.with_name(self.ckpt_path.name + ".tmp")
        torch.save(self.state(), tmp)
        tmp.replace(self.ckpt_path)

    def try_resume(self) -> int:
        if self.ckpt_path is None or not self.ckpt_path.exists():
            return 0
        s = torch.load(self.ckpt_path, map_location=self.sampler.device, weights_only=False)
        self.model.load_state_dict(s["model"])
        self.opt.load_state_dict(s["opt"])
        self.step, self.history = s["step"], s["history"]
        self.lr_scale, self.bad_total = s["lr_scale"], s.get("bad_total", 0)
        self.sampler.load_state_dict(s["sampler"])
        return self.step

    # -- loop --------------------------------------------------------------------------------
    def _set_lr(self) -> None:
        frac = self.step / max(self.cfg.steps, 1)
        cos = self.cfg.lr_decay + (1 - self.cfg.lr_decay) * 0.5 * (1 + math.cos(math.pi * frac))
        for g, base in zip(self.opt.param_groups, self.base_lrs):
            g["lr"] = base * cos * self.lr_scale

    def _autocast(self):
        if self.cfg.autocast == "bf16":
            return torch.autocast(self.sampler.device.type, dtype=torch.bfloat16)
        return contextlib.nullcontext()

    def fit(self) -> TrainResult:
        resumed = self.try_resume()
        t0 = time.perf_counter()
        bar = None
        if self.progress:
            from layercam.progress import bar as progress_bar

            bar = progress_bar(total=self.cfg.steps, initial=self.step, desc=self.desc, unit="step")
        bad_run = 0
        params = [p for g in self.opt.param_groups for p in g["params"]]
        last: dict = {}
        try:
            while self.step < self.cfg.steps:
                for cb in self.callbacks:
                    cb.on_step(self, self.step)
                self._set_lr()
                batch = self.sampler.sample(self.cfg.batch)
                with self._autocast():
                    terms = self.model.loss_dict(batch)
                loss = sum(terms.values())
                self.opt.zero_grad(set_to_none=True)
                ok = bool(torch.isfinite(loss))
                if ok:
                    loss.backward()
                    ok = all(p.grad is None or bool(torch.isfinite(p.grad).all()) for p in params)
                if not ok:
                    bad_run += 1
                    self.bad_total += 1
                    self.lr_scale *= 0.5
                    self.history.append({"step": self.step, "event": "non-finite loss or gradient: step skipped, lr halved"})
                    if bad_run >= self.cfg.max_bad_steps:
                        raise LayercamError(
                            f"training diverged: {bad_run} non-finite steps in a row at step {self.step}"
                            + (f"; last good checkpoint kept at {self.ckpt_path}" if self.ckpt_path else "")
                        )
                    self.step += 1
                    continue
                bad_run = 0
                self.opt.step()
                self.step += 1
                if self.step % 25 == 0 or self.step == self.cfg.steps or self.step == 1:
                    last = {k: float(v.detach()) for k, v in terms.items()}
                    last["total"] = float(loss)
                    self.history.append({"step": self.step, **last})
                    if bar is not None:
                        bar.set_postfix(loss=f"{last['total']:.4g}")
                if bar is not None:
                    bar.update(1)
                if self.ckpt_path and self.cfg.checkpoint_every and self.step % self.cfg.checkpoint_every == 0:
                    self.save()
        except KeyboardInterrupt:
            self.save()
            if bar is not None:
                bar.close()
            raise
        if bar is not None:
            bar.close()
        self.save()
        return TrainResult(self.step, time.perf_counter() - t0, self.history, last, self.bad_total, resumed)
