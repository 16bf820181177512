"""One training loop for every task. It knows no model: it sums ``model.loss_dict(batch)``.

Schedules are callbacks (nerfstudio's shape, :class:`Callback`), called before each step with the
step index; the model says which it needs (``model.training_callbacks``: the schedules of its loss
weights, :mod:`layercam.engine.losses`).
Guards: a non-finite loss or gradient (or a gradient norm that overflows) skips the step, halves
the learning rate and logs an event in the history (``report.json`` "train.events"); after
``MAX_BAD_STEPS`` in a row training stops with a clear error, keeping the last good checkpoint.
A periodic checkpoint is written only once the model it holds has produced a finite loss and
gradient on the next batch, and only when every parameter and optimiser moment is finite, so a
kept checkpoint is never a poisoned one.
Ctrl-C (or SIGTERM) stops training between two steps and saves a checkpoint there; the same command
resumes from it exactly where it stopped (the same result as a run that was not interrupted).
"""

from __future__ import annotations

import contextlib
import math
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from layercam.engine import distributed, optim

from layercam.core import interrupts
from layercam.core.config import TrainConfig
from layercam.core.errors import LayercamError

MAX_BAD_STEPS = 20  # non-finite steps in a row (each halving the learning rate) before training stops


class Callback:
    def on_step(self, trainer: "Trainer", step: int) -> None:  # pragma: no cover - interface
        pass


@dataclass
class TrainResult:
    steps: int
    seconds: float
    history: list
    final: dict
    bad_steps: int
    resumed_from: int
    cpu_seconds: float = 0.0  # process CPU time of the loop: steady when the machine is shared


class Trainer:
    def __init__(self, model, sampler, cfg: TrainConfig, ckpt_path: Path | None = None,
                 callbacks=(), progress: bool = True, desc: str = "train",
                 max_bad_steps: int | None = None):
        self.model, self.sampler, self.cfg = model, sampler, cfg
        self.max_bad_steps = MAX_BAD_STEPS if max_bad_steps is None else max_bad_steps
        self.ckpt_path = Path(ckpt_path) if ckpt_path else None
        self.callbacks = list(callbacks)
        self.progress, self.desc = progress, desc
        # sparse grid levels: only the rows a batch touches are read and updated (layercam/engine/optim.py)
        self.opt = optim.Adam(model.param_groups(cfg.lr, cfg.grid_lr), betas=(0.9, 0.99), eps=1e-15)
        self.loss_fn = distributed.loss_fn(model)  # model.loss_dict, through DDP inside a process group
        self.base_lrs = [g["lr"] for g in self.opt.param_groups]
        self.lr_scale = 1.0
        self.step = 0
        self.history: list = []
        self.bad_total = 0

    # -- checkpoints -------------------------------------------------------------------------
    def state(self, final: bool = False) -> dict:
        """What a checkpoint holds; ``final``: without the optimiser's moments (see :meth:`save`)."""
        return {
            "model": self.model.state_dict(),
            **({} if final else {"opt": self.opt.state_dict()}),
            "step": self.step,
            "history": self.history,
            "lr_scale": self.lr_scale,
            "sampler": self.sampler.state_dict(),
            "bad_total": self.bad_total,
        }

    def finite_state(self) -> bool:
        """True when every parameter and every optimiser moment is finite (worth checkpointing)."""
        with torch.no_grad():
            tensors = list(self.model.parameters()) + [
                v for st in self.opt.state.values() for v in st.values() if torch.is_tensor(v) and v.is_floating_point()
            ]
            return all(bool(torch.isfinite(v).all()) for v in tensors)

    def save(self, sampler_state: dict | None = None, final: bool = False) -> bool:
        """Write the checkpoint atomically; refuses (keeping the previous one) a non-finite state.
        ``final``: training has ended, so the optimiser's moments are left out (two thirds of the
        file, docs/measurements.md); a finished checkpoint resumes to its end without them."""
        if self.ckpt_path is None:
            return False
        if not distributed.is_main():
            return True  # rank 0 writes it (all ranks hold the same model)
        if not self.finite_state():
            self.history.append({"step": self.step,
                                 "event": "non-finite parameters: checkpoint not written, previous "
                                          "one kept"})
            return False
        state = self.state(final)
        if sampler_state is not None:
            state["sampler"] = sampler_state
        tmp = self.ckpt_path.with_name(self.ckpt_path.name + ".tmp")
        try:
            torch.save(state, tmp)
        except (OSError, RuntimeError) as e:  # torch reports a full disk as a RuntimeError of its zip writer
            with contextlib.suppress(OSError):
                tmp.unlink()
            raise LayercamError(f"cannot write the checkpoint {self.ckpt_path} (is the disk "
                                "full?): "
                                f"{str(e).splitlines()[0] if str(e) else type(e).__name__}; the "
                                "previous checkpoint is kept") from None
        tmp.replace(self.ckpt_path)
        return True

    def try_resume(self) -> int:
        if self.ckpt_path is None or not self.ckpt_path.exists():
            return 0
        s = torch.load(self.ckpt_path, map_location=self.sampler.device, weights_only=False)
        self.model.load_state_dict(s["model"])
        if "opt" in s:  # a final checkpoint has none: nothing is left to train
            self.opt.load_state_dict(s["opt"])
        elif s["step"] < self.cfg.steps:
            raise LayercamError(f"{self.ckpt_path} is a finished training's checkpoint (step "
                                f"{s['step']}), not one to train on to step {self.cfg.steps}")
        self.step, self.history = s["step"], s["history"]
        self.lr_scale, self.bad_total = s["lr_scale"], s.get("bad_total", 0)
        self.sampler.load_state_dict(s["sampler"])
        return self.step

    # -- loop --------------------------------------------------------------------------------
    def _set_lr(self) -> None:
        frac = self.step / max(self.cfg.steps, 1)
        cos = self.cfg.lr_decay + (1 - self.cfg.lr_decay) * 0.5 * (1 + math.cos(math.pi * frac))
        for g, base in zip(self.opt.param_groups, self.base_lrs):
            # a group with "start" (a fraction of training) stays frozen until then (Adam's moments
            # still gather, so its first steps are well scaled)
            g["lr"] = base * cos * self.lr_scale if frac >= g.get("start", 0.0) else 0.0

    def _autocast(self):
        dev = self.sampler.device
        auto = self.cfg.autocast == "auto" and dev.type == "cuda" and torch.cuda.is_bf16_supported()
        if self.cfg.autocast == "bf16" or auto:  # "auto": bf16 mixed precision on a GPU, fp32 on the CPU
            return torch.autocast(dev.type, dtype=torch.bfloat16)
        return contextlib.nullcontext()

    def fit(self) -> TrainResult:
        with interrupts.deferred() as pending:  # Ctrl-C is acted on between two steps
            return self._fit(pending)

    def _fit(self, pending) -> TrainResult:
        resumed = self.try_resume()
        t0, c0 = time.perf_counter(), time.process_time()
        bar = None
        if self.progress:
            from layercam.core.progress import bar as progress_bar

            bar = progress_bar(total=self.cfg.steps, initial=self.step, desc=self.desc, unit="step")
        bad_run = 0
        params = [p for g in self.opt.param_groups for p in g["params"]]
        last: dict = {}
        pending_save = False  # a checkpoint is due; written once the model passes the next step's checks
        try:
            while self.step < self.cfg.steps:
                interrupts.reached("train", self.step)
                if pending():  # stop here, where the state is whole
                    raise interrupts.Interrupted
                for cb in self.callbacks:
                    cb.on_step(self, self.step)
                self._set_lr()
                sampler_state = self.sampler.state_dict() if pending_save else None
                batch = self.sampler.sample(self.cfg.batch)
                with self._autocast():
                    terms = self.loss_fn(batch)
                loss = sum(terms.values())
                self.opt.zero_grad(set_to_none=True)
                bad = self._check(loss, terms, params)
                if bad:
                    bad_run += 1
                    self.bad_total += 1
                    self.lr_scale *= 0.5
                    self.history.append({"step": self.step,
                                         "event": f"{bad}: step skipped, lr halved "
                                                  f"(x{self.lr_scale:g})"})
                    if bad_run >= self.max_bad_steps:
                        err = LayercamError(
                            f"training diverged: {bad_run} non-finite steps in a row at step {self.step} ({bad}); "
                            + self._kept_message()
                            + "; try a lower train.lr or train.autocast=none"
                        )
                        err.events = [h for h in self.history if "event" in h][-20:]
                        raise err
                    self.step += 1
                    continue
                bad_run = 0
                if pending_save:
                    pending_save = not self.save(sampler_state)
                self.opt.step()
                self.step += 1
                if self.step % 25 == 0 or self.step == self.cfg.steps or self.step == 1:
                    last = {k: float(v.detach()) for k, v in terms.items()}
                    last["total"] = float(loss.detach())
                    self.history.append({"step": self.step, **last})
                    if bar is not None:
                        bar.set_postfix(loss=f"{last['total']:.4g}")
                if bar is not None:
                    bar.update(1)
                if self.ckpt_path and self.cfg.checkpoint_every and self.step % self.cfg.checkpoint_every == 0:
                    pending_save = True
        except interrupts.Interrupted:
            self.save()  # the state after the last whole step, with the sampler where it stood
            if bar is not None:
                bar.close()
            raise
        except KeyboardInterrupt:  # a second Ctrl-C, in the middle of a step: the last checkpoint stays
            if bar is not None:
                bar.close()
            raise
        if bar is not None:
            bar.close()
        self.opt.flush()  # sparse grid rows: the coasting since their last gradient (layercam/engine/optim.py)
        if not self.finite_state():
            raise LayercamError(f"training ended with non-finite parameters at step {self.step}; "
                                + self._kept_message())
        self.save(final=True)
        return TrainResult(self.step, time.perf_counter() - t0, self.history, last, self.bad_total,
                           resumed, time.process_time() - c0)

    @staticmethod
    def _check(loss: torch.Tensor, terms: dict, params: list) -> str:
        """Backpropagates a finite loss; returns "" when the step is good, else what went wrong."""
        if not bool(torch.isfinite(loss.detach())):
            names = [k for k, v in terms.items() if not bool(torch.isfinite(v.detach()).all())]
            return f"non-finite loss ({', '.join(names) or 'total'})"
        loss.backward()
        grads = [p.grad._values() if p.grad.is_sparse else p.grad for p in params
                 if p.grad is not None]  # sparse: its rows
        if grads and not bool(torch.isfinite(torch.nn.utils.get_total_norm(grads))):
            return "non-finite gradient norm"
        return ""

    def _kept_message(self) -> str:
        if self.ckpt_path is None:
            return "no checkpoint path was given"
        if not self.ckpt_path.exists():
            return "no good checkpoint had been written yet"
        step = torch.load(self.ckpt_path, map_location="cpu", weights_only=False).get("step")
        return f"last good checkpoint (step {step}) kept at {self.ckpt_path}"
