"""The model: its loss weights are a small dataclass, and it returns the schedules that change them."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch
from hypothesis import given, strategies as st

from layercam.core.presets import load_config
from layercam.core.errors import LayercamError
from layercam.engine.model import ALPHA_FLOW, ImplicitCameraModel, LossWeights

from conftest import TINY, decided, scaled_h0
from props import EV, _autocast, _finite, _grads_finite, props


def _model(layers=2, sets=(), **kw):
    h0 = torch.eye(3).expand(layers, 3, 3, 3).clone()
    cfg = decided(load_config("fast",
                              TINY
                              + ["train.steps=100", "train.bootstrap_steps=10",
                                 "train.passes_per_frame=0", *sets]), h0, layers=layers, **kw)
    return ImplicitCameraModel(cfg, h0, np.zeros(3), frame_hw=(16, 16))


def test_loss_weights_follow_the_model_components():
    w = _model(layers=1, tone_mapper="fixed", flow_loss=False).loss_weights
    assert isinstance(w, LossWeights) and (w.flow, w.white_balance, w.gradient, w.sparsity,
                      w.alpha_flow) == (0, 0, 0, 0, 0)
    w = _model(layers=2).loss_weights
    assert w.flow == 100.0 and w.sparsity > 0 and w.alpha_flow > 0 and w.alpha_mask == 0.0
    assert not hasattr(_model(layers=1).tone, "loss_weights")  # the tone mapper's own .weights are its parameters
    assert _model(layers=1).loss_weights.fg_follow == 0.0 and _model(layers=2).loss_weights.fg_follow > 0


def test_fg_follow_moves_only_the_foreground_atlas_towards_the_background():
    """The term that keeps the foreground's irradiance near the background's where alpha is low:
    its gradient reaches the foreground atlas only (not its deformation, the background or alpha),
    and a step against it brings the foreground nearer the background."""
    torch.manual_seed(0)
    model = _model(layers=2)
    w = model.loss_weights
    batch = {"xy": torch.rand(2048, 2) * 2 - 1, "t": torch.randint(0, 3, (2048,)), "rgb": torch.rand(2048, 3)}
    keep = w.fg_follow
    for k in vars(w):
        setattr(w, k, 0.0)
    w.fg_follow = keep
    term = model.loss_dict(batch)["fg_follow"]
    assert term.item() > 0
    term.backward()
    moved = {".".join(n.split(".")[1:3]) for n,
             p in model.named_parameters() if p.grad is not None and p.grad.abs().sum() > 0}
    assert moved == {"atlases.1"}, moved
    with torch.no_grad():
        for p in model.scene.atlases[1].parameters():
            if p.grad is not None:
                p -= 1e-2 * p.grad / (p.grad.norm() + 1e-12)
    assert model.loss_dict(batch)["fg_follow"].item() < term.item()


def test_schedules_change_the_weights_over_training():
    model = _model(layers=2)
    cbs = model.training_callbacks(masks=True)
    trainer = SimpleNamespace(model=model, cfg=model.cfg.train)
    seen = {}
    for step in (0, 9, 10, 25, 50, 99):
        for cb in cbs:
            cb.on_step(trainer, step)
        seen[step] = (model.loss_weights.flow, model.loss_weights.alpha_mask, model.loss_weights.mask_balance)
        if step >= 50:  # the alpha flow term outlives the flow, at its kept share (loss.alpha_flow_keep)
            assert model.loss_weights.alpha_flow == pytest.approx(ALPHA_FLOW * model.cfg.loss.alpha_flow_keep)
    # masks at full weight, class-balanced, during the bootstrap steps
    assert seen[0] == (100.0, 1.0, 1.0) and seen[9][1:] == (1.0, 1.0)
    assert seen[99][2] == 1.0  # motion masks: class-balanced all through
    assert 0 < seen[25][0] < 100 and 0 < seen[25][1] < 1  # both tapering
    assert seen[50][:2] == (0.0, 0.0) and seen[99][:2] == (0.0, 0.0)  # gone at flow_decay_end
    given = _model(layers=2)
    trainer = SimpleNamespace(model=given, cfg=given.cfg.train)
    balance, cbs = {}, given.training_callbacks(masks=True, given=True)
    for step in (0, 9, 10, 99):
        for cb in cbs:
            cb.on_step(trainer, step)
        balance[step] = (given.loss_weights.mask_balance, given.loss_weights.alpha_mask)
    # given masks: plain BCE after the bootstrap steps, kept at full weight
    assert balance == {0: (1.0, 1.0), 9: (1.0, 1.0), 10: (0.0, 1.0), 99: (0.0, 1.0)}
    one = _model(layers=1)
    one.training_callbacks(masks=True)
    assert one.loss_weights.alpha_mask == 0.0  # no alpha field to fit the masks to


def test_the_alpha_flow_term_outlives_the_flow_at_its_kept_share():
    """After the flow has decayed, alpha is still compared along the flow's matches at the share
    ``loss.alpha_flow_keep`` of its weight (the term needs alpha at the matches only); at 0 it goes
    with the flow, as before the setting. The long presets keep a share (their unheld steps
    drift), ``fast`` none (its short unheld phase refines alpha)."""
    assert load_config("balanced").loss.alpha_flow_keep == load_config("quality").loss.alpha_flow_keep == 0.25
    assert load_config("fast").loss.alpha_flow_keep == 0.0
    g = torch.Generator().manual_seed(0)
    n = 512
    xy = torch.rand(n, 2, generator=g) * 2 - 1
    batch = {"xy": xy, "t": torch.zeros(n, dtype=torch.long), "rgb": torch.rand(n, 3, generator=g),
             "xy_match": (xy + 0.05).clamp(-1, 1), "t_match": torch.ones(n, dtype=torch.long),
             "match_ok": torch.ones(n, dtype=torch.bool)}
    for keep in (1.0, 0.25, 0.0):
        model = _model(layers=2, sets=[f"loss.alpha_flow_keep={keep}"])
        cbs = model.training_callbacks()
        trainer = SimpleNamespace(model=model, cfg=model.cfg.train)
        for step in (0, 25, 60):  # 60: past flow_decay_end (0.5 of 100 steps)
            for cb in cbs:
                cb.on_step(trainer, step)
            if step == 25:
                assert model.loss_weights.alpha_flow == pytest.approx(ALPHA_FLOW * (keep + (1 - keep) * 0.5))
        terms = model.loss_dict(batch)
        assert "flow" not in terms and model.loss_weights.flow == 0.0
        assert model.loss_weights.alpha_flow == pytest.approx(ALPHA_FLOW * keep)
        if keep == 0:
            assert "alpha_flow" not in terms
            continue
        with torch.no_grad():
            a, am = model.scene.alpha(xy, batch["t"]), model.scene.alpha(batch["xy_match"], batch["t_match"])
        assert terms["alpha_flow"].item() == pytest.approx(keep * ALPHA_FLOW * (a - am).abs().mean().item(), rel=1e-5)
        terms["alpha_flow"].backward()
        grads = {n.split(".")[1] for n, p in model.named_parameters() if p.grad is not None and p.grad.abs().sum() > 0}
        assert grads == {"alpha"}, grads  # only the alpha field moves with it


def test_blur_group_carries_the_warmup():
    from layercam.camera.blur import WARMUP

    cfg = load_config("fast")
    h0 = torch.as_tensor(scaled_h0(1.0), dtype=torch.float32)
    blur_cfg = decided(cfg, h0, blur="3x3")
    groups = ImplicitCameraModel(blur_cfg, h0, np.zeros(2), frame_hw=(16, 16)).param_groups(1e-3, 1e-2)
    blur = [g for g in groups if g["name"] == "blur"]
    assert len(blur) == 1 and blur[0]["start"] == WARMUP > 0
    n_blur = sum(p.numel() for p in blur[0]["params"])
    model = ImplicitCameraModel(blur_cfg, h0, np.zeros(2), frame_hw=(16, 16))
    assert n_blur == sum(p.numel() for p in model.blur.parameters())
    assert not [g
                for g in ImplicitCameraModel(decided(cfg, h0), h0, np.zeros(2),
                                             frame_hw=(16, 16)).param_groups(1e-3, 1e-2)
                if g["name"] == "blur"]


@props(8)
@given(
    ev=EV, layers=st.sampled_from([1, 2]), robust=st.sampled_from([0.0, 0.05]),
    blur=st.sampled_from(["off", "3x3"]), target=st.sampled_from(["black", "white", "random"]),
    autocast=st.sampled_from(["none", "bf16"]),
)
def test_model_loss_terms_and_gradients_finite(ev, layers, robust, blur, target, autocast):
    from layercam.core.presets import load_config
    from layercam.engine.model import ImplicitCameraModel

    from conftest import decided

    torch.manual_seed(0)
    h0 = torch.eye(3).expand(layers, 2, 3, 3).clone()
    cfg = decided(load_config("fast", TINY + [f"loss.robust={robust}"]), h0, (3, 5), layers=layers, blur=blur)
    model = ImplicitCameraModel(cfg, h0, np.array([0.0, ev], np.float32), init_log2=-ev, frame_hw=(3, 5))
    n = 32
    rgb = {"black": torch.zeros(n, 3), "white": torch.ones(n, 3), "random": torch.rand(n, 3)}[target]
    batch = {"xy": torch.rand(n, 2) * 2 - 1, "t": torch.arange(n) % 2, "rgb": rgb,
             "xy_match": torch.rand(n, 2) * 2 - 1, "t_match": (torch.arange(n) + 1) % 2,
             "match_ok": torch.ones(n, dtype=torch.bool)}
    with _autocast(torch.bfloat16 if autocast == "bf16" else None):
        terms = model.loss_dict(batch)
    loss = sum(terms.values())
    assert _finite(*terms.values())
    loss.backward()
    assert _grads_finite(model)


def test_gradients_are_bit_identical_on_a_multithreaded_cpu():
    """Per-sample gathers of per-frame parameters (homography corrections, exposures, the blur
    embedding) go through ``gather_rows``: ``p[t]``'s backward
    accumulates with atomic adds on a multi-threaded CPU, so two identical steps gave different
    gradients (1e-9 on the first step) and a resumed run drifted from an uninterrupted one."""
    T, n = 24, 30_000
    h0 = torch.eye(3).expand(2, T, 3, 3).clone()
    cfg = decided(load_config("fast", TINY), h0, (16, 16), layers=2, blur="3x3", exposures="learned")
    g = torch.Generator().manual_seed(0)
    batch = {"xy": torch.rand(n, 2, generator=g) * 2 - 1,
             "t": torch.randint(0, T, (n,), generator=g), "rgb": torch.rand(n, 3, generator=g),
             "xy_match": torch.rand(n, 2, generator=g) * 2 - 1,
             "t_match": torch.randint(0, T, (n,), generator=g),
             "match_ok": torch.ones(n, dtype=torch.bool)}
    threads = torch.get_num_threads()
    torch.set_num_threads(4)
    try:
        grads = []
        for _ in range(2):
            torch.manual_seed(0)
            model = ImplicitCameraModel(cfg, h0, np.linspace(0, 3, T).astype(np.float32), frame_hw=(16, 16))
            sum(model.loss_dict(batch).values()).backward()
            grads.append({k: p.grad.coalesce().to_dense() if p.grad.is_sparse else p.grad.clone()
                          for k, p in model.named_parameters() if p.grad is not None})
    finally:
        torch.set_num_threads(threads)
    per_frame = [k for k in grads[0] if k.endswith(("dh", "delta", "embedding", "inc"))]
    assert len(per_frame) >= 3, sorted(grads[0])
    for k in grads[0]:
        assert torch.equal(grads[0][k], grads[1][k]), k


def test_loss_terms_do_not_read_the_global_rng():
    """A training step's random numbers all come from the sampler's stream (its state is in the
    checkpoint): the tone mapper's monotonicity term probes at the batch's own draws, so the terms
    are the same whatever the global RNG holds. It used ``torch.rand``: a resumed ``fuse-stack``
    run drifted from an uninterrupted one (up to 2 stops in the fused EXR) once that term woke."""
    from layercam.engine.sampler import PixelSampler

    model = _model(layers=1, flow_loss=False)
    with torch.no_grad():  # a tone curve that falls somewhere, so that the term is not 0
        for w in model.tone.weights:
            w.normal_(generator=torch.Generator().manual_seed(1))
    frames = np.random.default_rng(0).random((3, 16, 16, 3)).astype(np.float32)
    batch = PixelSampler(frames, seed=0).sample(64)
    other = PixelSampler(frames, seed=5).sample(64)
    terms = []
    for seed in (0, 1):
        torch.manual_seed(seed)
        terms.append({k: v.item() for k, v in model.loss_dict(batch).items()})
    assert terms[0] == terms[1] and terms[0]["gradient"] > 0
    assert model.loss_dict(other)["gradient"].item() != terms[0]["gradient"]  # the probe moves with the stream
    del batch["probe"]  # a hand-made batch: evenly spaced probes, still no global RNG
    torch.manual_seed(2)
    a = model.loss_dict(batch)["gradient"].item()
    torch.manual_seed(3)
    assert model.loss_dict(batch)["gradient"].item() == a > 0


def test_blurred_forward_in_one_scene_call_is_the_blur_generators_own():
    """With learned offsets the model reads the pixels and their PSFs' samples in one call of the
    scene; what it renders, and the gradients, are those of the scene at the pixels followed by the
    blur generator's own pass over the samples."""
    T, n = 3, 500
    h0 = torch.eye(3).expand(2, T, 3, 3).clone()
    cfg = decided(load_config("fast", TINY), h0, (16, 16), layers=2, blur="3x3")
    torch.manual_seed(0)
    model = ImplicitCameraModel(cfg, h0, np.zeros(T, np.float32), frame_hw=(16, 16))
    assert model.blur is not None and not model.blur.centre_fixed()
    with torch.no_grad():
        for p in model.blur.parameters():  # PSFs away from their start
            p.add_(torch.randn_like(p) * 0.3)
    g = torch.Generator().manual_seed(1)
    xy, t = torch.rand(n, 2, generator=g) * 2 - 1, torch.randint(0, T, (n,), generator=g)
    out = model(xy, t)
    sep = model.scene(xy, t)
    want = model.blur(model.scene, xy, t, sep)
    assert torch.allclose(out["log2_r_camera"], want, atol=1e-5)
    assert torch.allclose(out["alpha"], sep["alpha"]) and torch.allclose(out["uv"][1], sep["uv"][1])
    grads = []
    for r in (out["log2_r_camera"], want):
        model.zero_grad()
        (r.square().sum() + (out["alpha"] if r is out["log2_r_camera"] else sep["alpha"]).sum()).backward(
            retain_graph=True)
        grads.append({k: p.grad.coalesce().to_dense() if p.grad.is_sparse else p.grad.clone()
                      for k, p in model.named_parameters() if p.grad is not None})
    assert grads[0].keys() == grads[1].keys()
    for k in grads[0]:
        assert torch.allclose(grads[0][k], grads[1][k], atol=1e-4, rtol=1e-3), k
