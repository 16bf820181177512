"""The model: its loss weights are a small dataclass, and it returns the schedules that change them."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import torch

from layercam.config import load_config
from layercam.model import ImplicitCameraModel, LossWeights

from conftest import TINY, decided


def _model(layers=2, **kw):
    h0 = torch.eye(3).expand(layers, 3, 3, 3).clone()
    cfg = decided(load_config("fast", TINY + ["train.steps=100", "train.bootstrap_steps=10", "loss.flow_decay_end=0.5"]), h0, layers=layers, **kw)
    return ImplicitCameraModel(cfg, h0, np.zeros(3), frame_hw=(16, 16))


def test_loss_weights_follow_the_model_components():
    w = _model(layers=1, tone_mapper="fixed", flow_loss=False).loss_weights
    assert isinstance(w, LossWeights) and (w.flow, w.white_balance, w.gradient, w.sparsity, w.alpha_flow) == (0, 0, 0, 0, 0)
    w = _model(layers=2).loss_weights
    assert w.flow == 100.0 and w.sparsity > 0 and w.alpha_flow > 0 and w.alpha_mask == 0.0
    assert not hasattr(_model(layers=1).tone, "loss_weights")  # the tone mapper's own .weights are its parameters


def test_schedules_change_the_weights_over_training():
    model = _model(layers=2)
    cbs = model.training_callbacks(masks=True)
    trainer = SimpleNamespace(model=model, cfg=model.cfg.train)
    seen = {}
    for step in (0, 9, 10, 25, 50, 99):
        for cb in cbs:
            cb.on_step(trainer, step)
        seen[step] = (model.loss_weights.flow, model.loss_weights.alpha_mask)
    assert seen[0] == (100.0, 1.0) and seen[9][1] == 1.0  # masks at full weight during the bootstrap steps
    assert 0 < seen[25][0] < 100 and 0 < seen[25][1] < 1  # both tapering
    assert seen[50] == (0.0, 0.0) and seen[99] == (0.0, 0.0)  # gone at flow_decay_end
    one = _model(layers=1)
    one.training_callbacks(masks=True)
    assert one.loss_weights.alpha_mask == 0.0  # no alpha field to fit the masks to
