"""How a blur model is sized and trained: the atlas grid is no finer than the pixels, the PSFs are
held at their start for a warm-up, and saved runs keep the grid sizes they were trained with."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from layercam.config import TrainConfig, load_config
from layercam.errors import LayercamError
from layercam.checkpoint import load_run_model, save_run_model
from layercam.geometry import atlas_pixels
from layercam.model import ImplicitCameraModel
from layercam.train import Trainer

from conftest import decided
from test_guards import ToySampler


def _h0(scale: float, frames: int = 2) -> np.ndarray:
    """Identity mappings shrunk by ``scale``: the frame covers ``scale`` of the atlas."""
    return np.tile(np.diag([scale, scale, 1.0])[None, None], (1, frames, 1, 1))


def test_grid_no_finer_than_pixels_with_blur():
    cfg = load_config("fast")
    h0 = _h0(0.9)
    px = atlas_pixels(h0, (64, 64))
    assert abs(px - 64 / 0.9) < 1e-6
    sharp = decided(cfg, h0, (64, 64), blur="off").scene.grid_max_res
    blurred = decided(cfg, h0, (64, 64), blur="3x3").scene.grid_max_res
    assert sharp == 128  # power of two at or above 71.1 px: at least one cell per pixel
    assert blurred == 71  # the extent itself: at most one cell per pixel
    forced = load_config("fast", ["scene.grid_max_res=256"])
    assert decided(forced, h0, (64, 64), blur="3x3").scene.grid_max_res == 256  # a set size wins
    m = ImplicitCameraModel(decided(cfg, h0, (64, 64), blur="3x3"), torch.as_tensor(h0, dtype=torch.float32), np.zeros(2), frame_hw=(64, 64))
    assert m.scene.atlases[0].enc.resolutions[-1] == 71


class TwoParams(nn.Module):
    """``loss = |a - 1|^2 + |b - 1|^2``; ``b`` is in a group that starts at half of training."""

    def __init__(self):
        super().__init__()
        self.a, self.b = nn.Parameter(torch.zeros(2)), nn.Parameter(torch.zeros(2))

    def loss_dict(self, batch):
        return {"color": ((self.a - 1) ** 2).sum() + ((self.b - 1) ** 2).sum()}

    def param_groups(self, lr, grid_lr):
        return [{"params": [self.a], "lr": lr, "name": "mlp"}, {"params": [self.b], "lr": lr, "name": "blur", "start": 0.5}]


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


def test_blur_group_carries_the_warmup():
    cfg = load_config("fast", ["blur.warmup=0.3"])
    h0 = torch.as_tensor(_h0(1.0), dtype=torch.float32)
    blur_cfg = decided(cfg, h0, blur="3x3")
    groups = ImplicitCameraModel(blur_cfg, h0, np.zeros(2), frame_hw=(16, 16)).param_groups(1e-3, 1e-2)
    blur = [g for g in groups if g["name"] == "blur"]
    assert len(blur) == 1 and blur[0]["start"] == 0.3
    n_blur = sum(p.numel() for p in blur[0]["params"])
    model = ImplicitCameraModel(blur_cfg, h0, np.zeros(2), frame_hw=(16, 16))
    assert n_blur == sum(p.numel() for p in model.blur.parameters())
    assert not [g for g in ImplicitCameraModel(decided(cfg, h0), h0, np.zeros(2), frame_hw=(16, 16)).param_groups(1e-3, 1e-2) if g["name"] == "blur"]
    with pytest.raises(LayercamError, match="blur.warmup"):
        load_config("fast", ["blur.warmup=1"])


def test_saved_run_keeps_its_grid_sizes(tmp_path):
    """A run saved with the derived sizes left at 0 (older runs) is rebuilt from its saved grids;
    a run saved now stores the sizes it was built with."""
    cfg = load_config("fast", ["scene.grid_levels=3"])
    h0 = _h0(0.8, frames=3)
    meta = {"h0": h0, "log2_dt": np.zeros(3), "exposure_learn": "none", "phase": None, "init_log2": 0.0, "frame_hw": (40, 40)}
    model = ImplicitCameraModel(decided(cfg, h0, (40, 40), blur="3x3"), torch.as_tensor(h0, dtype=torch.float32), np.zeros(3), frame_hw=(40, 40))
    grids = [tuple(p.shape[-2:]) for n, p in model.named_parameters() if ".enc.grids." in n]
    assert grids[-1] == (50, 50)
    # as an older version wrote it: cfg with grid_max_res = 0 and the model chosen in a "spec"
    spec = {"layers": 1, "tone_mapper": "learned", "exposures": "given", "blur": "3x3", "max_offset": 5.0, "flow_loss": True, "reasons": {}}
    torch.save({"state": model.state_dict(), "cfg": {k: v for k, v in cfg.to_dict().items() if k != "model"}, "spec": spec, **meta}, tmp_path / "checkpoint.pt")
    loaded, _ = load_run_model(tmp_path)
    assert [tuple(p.shape[-2:]) for n, p in loaded.named_parameters() if ".enc.grids." in n] == grids
    # as written now
    (tmp_path / "new").mkdir()
    save_run_model(tmp_path / "new" / "checkpoint.pt", model, meta)
    ck = torch.load(tmp_path / "new" / "checkpoint.pt", weights_only=False)
    assert ck["cfg"]["scene"]["grid_max_res"] == 50
    loaded, _ = load_run_model(tmp_path / "new")
    xy = torch.rand(7, 2) * 2 - 1
    t = torch.zeros(7, dtype=torch.long)
    assert torch.allclose(loaded(xy, t)["rgb"], model.eval()(xy, t)["rgb"])


@pytest.mark.parametrize("mode,expect_residual", [("auto", False), ("on", True)])
def test_static_stack_drops_the_residual_warp(tmp_path, mode, expect_residual):
    """A static one-layer stack (identity bootstrap): with scene.residual=auto the deformation is
    the per-frame homographies only; =on keeps the residual MLP. blur.centre=auto centres its PSFs.
    The saved run rebuilds the same."""
    from layercam import synth
    from layercam.io import Exposures
    from layercam.pipelines.tasks import run_task

    from conftest import SMALL_BLUR, TINY

    sc = synth.mfme_stack(size=(64, 64), focus_settings=2, exposures_ev=(0.0,), planes=2, seed=3)
    exp = Exposures(np.zeros(2), "none", None, "none", "single")
    cfg = load_config("fast", TINY + SMALL_BLUR + ["train.steps=20", f"scene.residual={mode}", "model.layers=1"])
    ctx = run_task("fuse-stack", sc.clip, exp, cfg, tmp_path / "run", progress=False)
    assert ctx.results["bootstrap"]["static"] is True
    model, ck = load_run_model(tmp_path / "run")
    d = model.scene.deformations[0]
    assert (d.residual_scale > 0) == expect_residual
    assert (ck["cfg"]["scene"]["residual_scale"] > 0) == expect_residual
    assert ck["cfg"]["blur"]["centre"] == "on" and model.blur.centre_exact
    disp, w = model.blur.kernels(torch.rand(50, 2) * 2 - 1, torch.randint(0, 2, (50,)))
    assert torch.allclose((w[:, :, None] * disp).sum(1), torch.zeros(50, 2), atol=1e-4)
    with pytest.raises(LayercamError, match="scene.residual"):
        load_config("fast", ["scene.residual=maybe"])
    with pytest.raises(LayercamError, match="blur.centre"):
        load_config("fast", ["blur.centre=maybe"])


def test_moving_clip_keeps_psf_shift_free(tmp_path):
    """A clip whose camera moves (a pan, not static): blur.centre=auto resolves to off, residual kept."""
    from layercam import synth
    from layercam.io import Exposures
    from layercam.pipelines.tasks import run_task

    from conftest import SMALL_BLUR, TINY

    sc = synth.pan_hdr(frames=3, size=(48, 48), ev_step=0.0, seed=0)  # pans 1.5 to 3 px a frame
    cfg = load_config("fast", TINY + SMALL_BLUR + ["train.steps=10", "model.layers=1", "model.blur=on", "blur.n=3"])
    ctx = run_task("deblur-video", sc.clip, Exposures(np.zeros(3), "none", None, "none", "single"), cfg, tmp_path / "run", progress=False)
    assert ctx.results["bootstrap"]["static"] is False
    model, ck = load_run_model(tmp_path / "run")
    assert ck["cfg"]["blur"]["centre"] == "off" and not model.blur.centre_exact
    assert model.scene.deformations[0].residual_scale > 0
