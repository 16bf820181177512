"""Tests of layercam.engine.train: one loop for every model; the non-finite step guard and its checkpoints
(on a toy model, exact), the guard in the pipeline (report.json, report_failed.json, resume), and
parameter groups held until their start."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from torch import nn

from layercam.core.config import TrainConfig

from layercam.core.presets import load_config
from layercam.core.errors import LayercamError
from layercam.io import read_exr
from layercam.pipelines.tasks import run_task
from layercam.engine.train import Trainer

from conftest import TINY


class TwoParams(nn.Module):
    """``loss = |a - 1|^2 + |b - 1|^2``; ``b`` is in a group that starts at half of training."""

    def __init__(self):
        super().__init__()
        self.a, self.b = nn.Parameter(torch.zeros(2)), nn.Parameter(torch.zeros(2))

    def loss_dict(self, batch):
        return {"color": ((self.a - 1) ** 2).sum() + ((self.b - 1) ** 2).sum()}

    def param_groups(self, lr, grid_lr):
        return [{"params": [self.a], "lr": lr, "name": "mlp"},
                {"params": [self.b], "lr": lr, "name": "blur", "start": 0.5}]


class Record:
    def __init__(self):
        self.b = []

    def on_step(self, trainer, step):
        self.b.append(trainer.model.b.detach().clone())


def test_group_with_start_is_held_until_then(tmp_path):
    model, rec = TwoParams(), Record()
    cfg = TrainConfig(steps=20, lr=0.05, lr_decay=1.0, checkpoint_every=0)
    Trainer(model, ToySampler(), cfg, None, callbacks=[rec], progress=False).fit()
    assert all(torch.equal(b, torch.zeros(2)) for b in rec.b[:11])  # steps 0..10: frac <= 0.5 when stepped
    assert not torch.equal(rec.b[-1], torch.zeros(2)) and (model.b > 0.2).all()
    assert (model.a > 0.5).all()


class ToyModel(nn.Module):
    """``loss = |w - 1|^2``; ``nan_loss_at`` / ``nan_grad_at`` (sets of call indices) inject NaNs."""

    def __init__(self, nan_loss_at=(), nan_grad_at=()):
        super().__init__()
        self.w = nn.Parameter(torch.zeros(3))
        self.calls = 0
        self.nan_loss_at, self.nan_grad_at = set(nan_loss_at), set(nan_grad_at)

    def loss_dict(self, batch):
        i = self.calls
        self.calls += 1
        w = self.w
        if i in self.nan_grad_at:  # finite loss, NaN gradient
            w = w + 0.0
            w.register_hook(lambda g: g * float("nan"))
        loss = ((w - 1.0) ** 2).sum()
        if i in self.nan_loss_at:
            loss = loss * float("nan")
        return {"color": loss}

    def param_groups(self, lr, grid_lr):
        return [{"params": [self.w], "lr": lr, "name": "mlp"}]


class ToySampler:
    device = torch.device("cpu")

    def __init__(self):
        self.gen = torch.Generator().manual_seed(0)

    def sample(self, n):
        torch.rand(1, generator=self.gen)
        return {}

    def state_dict(self):
        return {"gen": self.gen.get_state()}

    def load_state_dict(self, s):
        self.gen.set_state(s["gen"])


def _trainer(model, tmp_path, steps=20, every=5, max_bad=3):
    cfg = TrainConfig(steps=steps, lr=0.05, lr_decay=1.0, checkpoint_every=every)
    return Trainer(model, ToySampler(), cfg, tmp_path / "ckpt.pt", progress=False, max_bad_steps=max_bad)


def test_non_finite_loss_skips_step_halves_lr_and_logs(tmp_path):
    model = ToyModel(nan_loss_at={4, 5})
    tr = _trainer(model, tmp_path)
    res = tr.fit()
    events = [h for h in res.history if "event" in h]
    assert res.bad_steps == 2 and [e["step"] for e in events] == [4, 5]
    assert "non-finite loss (color)" in events[0]["event"] and "x0.25" in events[1]["event"]
    assert tr.lr_scale == 0.25 and tr.opt.param_groups[0]["lr"] == pytest.approx(0.05 * 0.25)
    assert torch.isfinite(model.w).all() and float((model.w.detach() - 1).abs().max()) < 1.0


def test_non_finite_gradient_with_finite_loss_is_caught_and_step_skipped(tmp_path):
    model = ToyModel(nan_grad_at={3})
    tr = _trainer(model, tmp_path, steps=6)
    seen = {}

    class Spy:
        def on_step(self, trainer, step):
            seen[step] = trainer.model.w.detach().clone()

    tr.callbacks.append(Spy())
    res = tr.fit()
    assert [h["event"].split(":")[0] for h in res.history if "event" in h] == ["non-finite gradient norm"]
    assert torch.equal(seen[3], seen[4]), "the bad step must not move the parameters"
    assert torch.isfinite(model.w).all()


def test_divergence_stops_with_clear_message_and_keeps_last_good_checkpoint(tmp_path):
    # the update at the end of step 9 poisons the parameters, right before the step-10 checkpoint
    model = ToyModel()
    tr = _trainer(model, tmp_path, steps=40, every=5, max_bad=3)
    real_step = tr.opt.step

    def poisoning_step(*a, **k):
        out = real_step(*a, **k)
        if tr.step == 9:
            with torch.no_grad():
                model.w.fill_(float("nan"))
        return out

    tr.opt.step = poisoning_step
    with pytest.raises(LayercamError) as err:
        tr.fit()
    msg = str(err.value)
    assert "training diverged: 3 non-finite steps in a row at step 12" in msg
    assert "last good checkpoint (step 5)" in msg and "train.lr" in msg
    assert len(err.value.events) == 3
    ck = torch.load(tmp_path / "ckpt.pt", weights_only=False)
    assert ck["step"] == 5 and torch.isfinite(ck["model"]["w"]).all()
    # it resumes from the good checkpoint, and without the poison it finishes
    tr2 = _trainer(ToyModel(), tmp_path, steps=40, every=5, max_bad=3)
    res = tr2.fit()
    assert res.resumed_from == 5 and res.steps == 40 and torch.isfinite(tr2.model.w).all()


def test_divergence_before_any_checkpoint_says_so(tmp_path):
    model = ToyModel(nan_loss_at=set(range(2, 100)))
    with pytest.raises(LayercamError, match="no good checkpoint had been written yet"):
        _trainer(model, tmp_path, every=5, max_bad=4).fit()
    assert not (tmp_path / "ckpt.pt").exists()


def test_a_checkpoint_that_cannot_be_written_is_one_clear_error_and_keeps_the_last(tmp_path, monkeypatch):
    """A full disk mid-save (torch's zip writer raises a RuntimeError): a LayercamError naming the
    checkpoint, no temp file left, the previous checkpoint untouched."""
    from layercam.core.errors import LayercamError

    tr = _trainer(ToyModel(), tmp_path, steps=4)
    tr.fit()
    before = (tmp_path / "ckpt.pt").read_bytes()

    def full_disk(obj, f, *a, **k):
        type(tmp_path)(f).write_bytes(b"partial")
        raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 570991360 vs 570991248")

    monkeypatch.setattr(torch, "save", full_disk)
    with pytest.raises(LayercamError, match="cannot write the checkpoint .*disk full"):
        tr.save()
    assert (tmp_path / "ckpt.pt").read_bytes() == before
    assert not (tmp_path / "ckpt.pt.tmp").exists()


def test_checkpoint_refuses_non_finite_state_and_final_state_is_checked(tmp_path):
    model = ToyModel()
    tr = _trainer(model, tmp_path, steps=4)
    tr.fit()
    before = (tmp_path / "ckpt.pt").read_bytes()
    with torch.no_grad():
        model.w[0] = float("inf")
    assert tr.save() is False and (tmp_path / "ckpt.pt").read_bytes() == before
    # poisoned by the very last update: the run refuses to finish with it
    model2 = ToyModel()
    (tmp_path / "x").mkdir()
    tr2 = _trainer(model2, tmp_path / "x", steps=4)
    real_step = tr2.opt.step

    def last_poisons(*a, **k):
        out = real_step(*a, **k)
        if tr2.step == 3:
            with torch.no_grad():
                model2.w.fill_(float("nan"))
        return out

    tr2.opt.step = last_poisons
    with pytest.raises(LayercamError, match="non-finite parameters"):
        tr2.fit()


def _nan_loss_from(monkeypatch, bad_calls):
    """The trainer's ``bad_calls(i)``-th loss made non-finite (the trainer's own calls: the memory
    estimate also evaluates a model's loss)."""
    from layercam.engine import distributed

    real = distributed.loss_fn
    calls = {"n": 0}

    def loss_fn(model):
        inner = real(model)

        def terms_of(batch):
            terms = inner(batch)
            i = calls["n"]
            calls["n"] += 1
            if bad_calls(i):
                terms["color"] = terms["color"] * float("nan")
            return terms

        return terms_of

    monkeypatch.setattr(distributed, "loss_fn", loss_fn)


def test_pipeline_logs_skipped_steps_in_report(tiny_scene, tiny_exposures, tmp_path, monkeypatch):
    _nan_loss_from(monkeypatch, lambda i: i in (5, 6, 7))
    cfg = load_config("fast", TINY + ["train.steps=20"])
    run_task("hdr-video", tiny_scene.clip, tiny_exposures, cfg, tmp_path / "run", progress=False)
    rep = json.loads((tmp_path / "run" / "report.json").read_text())
    ev = rep["train"]["events"]
    assert rep["train"]["bad_steps"] == 3 and [e["step"] for e in ev] == [5, 6, 7]
    assert all("non-finite loss (color)" in e["event"] for e in ev)
    for p in (tmp_path / "run" / "hdr").glob("*.exr"):
        assert np.isfinite(read_exr(p)).all()


def test_pipeline_divergence_writes_failed_report_keeps_checkpoint_and_resumes(tiny_scene,
    tiny_exposures, tmp_path, monkeypatch):
    cfg = load_config("fast", TINY + ["train.steps=20", "train.checkpoint_every=5"])
    monkeypatch.setattr("layercam.engine.train.MAX_BAD_STEPS", 4)
    _nan_loss_from(monkeypatch, lambda i: i >= 10)
    with pytest.raises(LayercamError, match="training diverged: 4 non-finite steps in a row at step 13"):
        run_task("hdr-video", tiny_scene.clip, tiny_exposures, cfg, tmp_path / "run", progress=False)
    run = tmp_path / "run"
    assert not (run / "report.json").exists()
    failed = json.loads((run / "report_failed.json").read_text())
    assert "diverged" in failed["error"] and len(failed["train"]["events"]) == 4
    (ckpt,) = run.glob("cache/train-*/ckpt.pt")
    ck = torch.load(ckpt, weights_only=False)
    assert ck["step"] == 5 and all(torch.isfinite(v).all() for v in ck["model"].values() if v.is_floating_point())
    monkeypatch.undo()
    ctx = run_task("hdr-video", tiny_scene.clip, tiny_exposures, cfg, run, progress=False)
    assert ctx.results["train"].resumed_from == 5 and ctx.results["train"].steps == 20
    assert (run / "report.json").exists() and not (run / "report_failed.json").exists()


def test_mask_taper_decays_to_its_floor():
    from types import SimpleNamespace

    from layercam.engine.model import LossWeights
    from layercam.engine.losses import MaskTaper

    for floor, last in ((0.0, 0.0), (1.0, 2.0), (0.25, 0.5)):
        trainer = SimpleNamespace(model=SimpleNamespace(loss_weights=LossWeights(alpha_mask=2.0)),
                                  cfg=SimpleNamespace(steps=100))
        taper = MaskTaper(steps=10, end=0.5, floor=floor)
        seen = []
        for step in (0, 9, 30, 50, 99):
            taper.on_step(trainer, step)
            seen.append(trainer.model.loss_weights.alpha_mask)
        assert seen[:2] == [2.0, 2.0] and seen[-1] == last and seen[-2] == last
        assert seen[2] == pytest.approx(max(2.0 * (1 - 20 / 40), last))
