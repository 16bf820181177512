"""Guards that keep a run finite: the trainer's non-finite step guard and its checkpoints, the
export's checks, tiny frames through flow, the clipped-pixel colour loss, float32 geometry."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from torch import nn

from layercam.config import TrainConfig, load_config
from layercam.errors import LayercamError
from layercam.io import Clip, Exposures, read_exr
from layercam.pipelines.tasks import run_task
from layercam.train import Trainer

from conftest import TINY


# ------------------------------------------------------------------------------------------
# the trainer's guard on a toy model (fast, exact)
# ------------------------------------------------------------------------------------------


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
    cfg = TrainConfig(steps=steps, lr=0.05, lr_decay=1.0, checkpoint_every=every, max_bad_steps=max_bad)
    return Trainer(model, ToySampler(), cfg, tmp_path / "ckpt.pt", progress=False)


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


# ------------------------------------------------------------------------------------------
# the guard in the pipeline: report.json, report_failed.json, resume
# ------------------------------------------------------------------------------------------


def _nan_loss_from(monkeypatch, bad_calls):
    from layercam.model import ImplicitCameraModel

    real = ImplicitCameraModel.loss_dict
    calls = {"n": 0}

    def loss_dict(self, batch):
        terms = real(self, batch)
        i = calls["n"]
        calls["n"] += 1
        if bad_calls(i):
            terms["color"] = terms["color"] * float("nan")
        return terms

    monkeypatch.setattr(ImplicitCameraModel, "loss_dict", loss_dict)


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


def test_pipeline_divergence_writes_failed_report_keeps_checkpoint_and_resumes(tiny_scene, tiny_exposures, tmp_path, monkeypatch):
    cfg = load_config("fast", TINY + ["train.max_bad_steps=4", "train.steps=20", "train.checkpoint_every=5"])
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
    assert ctx.results["train"]["resumed_from"] == 5 and ctx.results["train"]["steps"] == 20
    assert (run / "report.json").exists() and not (run / "report_failed.json").exists()


# ------------------------------------------------------------------------------------------
# export, flow on tiny frames, geometry precision, clipped pixels
# ------------------------------------------------------------------------------------------


def _clip(frames):
    return Clip(frames=np.asarray(frames, np.float32), source="test", names=[str(i) for i in range(len(frames))])


def test_export_writes_float32_when_irradiance_exceeds_half(tmp_path):
    # white frames at exposures 2^-12: the irradiance starts near 2^21, beyond half floats
    ex = Exposures(np.array([-12.0, -11.0]), "none", np.array([0, 1]), "alt", "test")
    cfg = load_config("fast", TINY + ["train.steps=4", "train.batch=64"])
    ctx = run_task("hdr-video", _clip(np.ones((2, 8, 8, 3))), ex, cfg, tmp_path / "run", progress=False)
    assert ctx.results["export"]["exr"] == "float32"
    img = read_exr(tmp_path / "run" / "hdr" / "frame_00000.exr")
    assert np.isfinite(img).all() and img.max() > 65504


def test_export_refuses_non_finite_render(tiny_scene, tiny_exposures, tmp_path, monkeypatch):
    import layercam.render as render

    real = render.render_frame

    def nan_render(*a, **k):
        out = real(*a, **k)
        out["hdr"][0, 0, 0] = np.nan
        return out

    monkeypatch.setattr(render, "render_frame", nan_render)
    cfg = load_config("fast", TINY + ["train.steps=4"])
    with pytest.raises(LayercamError, match="non-finite irradiance"):
        run_task("hdr-video", tiny_scene.clip, tiny_exposures, cfg, tmp_path / "run", progress=False)
    assert not list((tmp_path / "run").glob("hdr/*.exr"))


@pytest.mark.parametrize("hw", [(1, 1), (2, 3), (5, 7), (11, 40)])
def test_flow_on_frames_smaller_than_dis_patches(hw):
    from layercam.flow import compute_flow

    frames = np.random.default_rng(0).random((3, *hw, 3)).astype(np.float32)
    fw, bw = compute_flow(frames, method="dis_fast", progress=False)
    assert fw.shape == bw.shape == (2, *hw, 2) and np.isfinite(fw).all() and np.isfinite(bw).all()


def test_homography_runs_in_float32_under_autocast():
    from layercam.scene.fields import apply_homography

    h = torch.eye(3).expand(64, 3, 3).clone()
    h[:, 0, 2] = 0.123456
    h[:, 2, 0] = 0.01
    xy = torch.rand(64, 2) * 2 - 1
    ref = apply_homography(h, xy)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = apply_homography(h, xy)
    assert out.dtype == torch.float32 and torch.equal(out, ref)


def test_one_sided_loss_measures_clipped_pixels_against_the_threshold():
    from layercam import losses

    target = torch.tensor([[1.0, 0.0, 0.5]])
    # a sigmoid curve never reaches 1: past the threshold a clipped pixel is satisfied
    assert float(losses.color_loss(torch.tensor([[0.998, 0.003, 0.5]]), target, "one_sided")) == 0.0
    # on the wrong side of the threshold it still costs (and plain MSE always does)
    assert float(losses.color_loss(torch.tensor([[0.9, 0.003, 0.5]]), target, "one_sided")) > 0
    assert float(losses.color_loss(torch.tensor([[0.998, 0.003, 0.5]]), target, "plain")) > 0


def test_highlight_psnr_mu_restricts_psnr_mu_to_the_mask():
    from layercam import metrics

    rng = np.random.default_rng(0)
    gt = rng.random((2, 8, 8, 3)).astype(np.float32) * 4
    pred = gt.copy()
    pred[:, :2] *= 1.3  # wrong only in the top quarter (the median alignment keeps the rest exact)
    top = np.zeros((2, 8, 8), bool)
    top[:, :2] = True
    assert metrics.highlight_psnr_mu(pred, gt, np.ones_like(top)) == pytest.approx(metrics.psnr_mu(pred, gt))
    assert metrics.highlight_psnr_mu(pred, gt, top) < metrics.psnr_mu(pred, gt) < metrics.highlight_psnr_mu(pred, gt, ~top)
    with pytest.raises(metrics.MetricInputError):
        metrics.highlight_psnr_mu(pred, gt, np.zeros_like(top))


@pytest.mark.slow
def test_one_sided_loss_improves_clipped_highlights(tmp_path):
    """synth.pan_hdr at +5 EV (29% of the pixels clip in the long exposure), fast preset: PSNR-mu over
    the pixels clipped in some exposure, plain MSE against the one-sided loss (measured: 32.6 -> 33.8 dB)."""
    from layercam import metrics, synth

    scene = synth.pan_hdr(frames=8, size=(64, 64), ev_step=5.0, seed=0)
    log2 = np.log2(scene.exposure_times / scene.exposure_times.min())
    ex = Exposures(log2, "none", np.arange(8) % 2, "alt", "test")
    white = 1.0 / (scene.meta["gain"] * scene.exposure_times.max())
    clipped = (scene.hdr >= white).any(-1)
    hl = {}
    for mode in ("plain", "one_sided"):
        cfg = load_config("fast", ["flow.method=dis_fast", f"loss.clipped={mode}"])
        run_task("hdr-video", scene.clip, ex, cfg, tmp_path / mode, progress=False)
        pred = np.stack([read_exr(tmp_path / mode / "hdr" / f"frame_{t:05d}.exr") for t in range(8)])
        hl[mode] = metrics.highlight_psnr_mu(pred, scene.hdr, clipped)
    assert hl["one_sided"] > hl["plain"] + 0.5, hl
