"""Where a run trains: ``--device auto`` (the default) is CUDA when torch sees a GPU, else the CPU,
and the run says which; the model, the optimiser's state and the sampler's tensors follow the
device; bf16 autocast trains. What needs a GPU is skipped without one (these machines have none)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from layercam.core.presets import load_config
from layercam.core.errors import LayercamError
from layercam.engine.resolve import device_of
from layercam.pipelines.stages import device_line
from layercam.pipelines.tasks import run_task

from conftest import TINY, decided

CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
DEVICES = ["cpu", pytest.param("cuda", marks=CUDA)]


def test_auto_is_the_default_and_resolves_to_what_torch_sees(monkeypatch):
    assert load_config("fast").train.device == "auto"
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert device_of("auto") == "cpu"
    assert device_line("auto", "cpu") == "cpu (auto: torch sees no CUDA device)"
    with pytest.raises(LayercamError, match="CUDA"):
        device_of("cuda")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert device_of("auto") == "cuda" and device_of("cuda:1") == "cuda:1"
    assert device_line("cpu", "cpu") == "cpu (asked for)"
    with pytest.raises(LayercamError, match="train.device"):
        load_config("fast", ["train.device=tpu"])


def test_a_run_says_where_it_trains(tiny_scene, tiny_exposures, tmp_path):
    ctx = run_task("hdr-video", tiny_scene.clip, tiny_exposures, load_config("fast", TINY),
                   tmp_path / "run", progress=False)
    want = device_of("auto")
    assert any(m.startswith(f"[train] device: {want} (auto: ") for m in ctx.log)
    tr = json.loads((tmp_path / "run" / "report.json").read_text())["train"]
    assert tr["device"] == want and tr["device_asked"] == "auto"


def _tiny_trainer(device: str, autocast: str = "none", steps: int = 30):
    from layercam.engine.sampler import PixelSampler
    from layercam.engine.model import ImplicitCameraModel
    from layercam.synth import pan_hdr
    from layercam.engine.train import Trainer

    scene = pan_hdr(frames=3, size=(24, 24), seed=2)
    h0 = np.tile(np.diag([0.4, 0.4, 1.0])[None, None], (1, 3, 1, 1))  # the frames span 60 px of the
                                                                      # atlas: a 64^2 level, trained
                                                                      # sparsely
    cfg = decided(load_config("fast",
                              TINY + [f"train.steps={steps}", f"train.autocast={autocast}"]), h0,
                  (24, 24), flow_loss=False)
    log2_dt = np.log2(scene.exposure_times / scene.exposure_times.min())
    torch.manual_seed(0)
    model = ImplicitCameraModel(cfg, torch.as_tensor(h0, dtype=torch.float32), log2_dt, frame_hw=(24, 24)).to(device)
    return Trainer(model, PixelSampler(scene.clip.frames, device=device), cfg.settings.train, progress=False)


@pytest.mark.parametrize("device", DEVICES)
def test_model_optimiser_state_and_sampler_follow_the_device(device):
    tr = _tiny_trainer(device, steps=5)
    tr.fit()
    dev = torch.device(device).type
    sparse = [p for p in tr.model.parameters() if p.grad is not None and p.grad.is_sparse]
    assert sparse, "the tiny preset should train sparse grid levels"
    assert all(p.device.type == dev for p in tr.model.parameters())
    assert all(v.device.type == dev for st in tr.opt.state.values() for k, v in st.items() if k != "step")
    assert all(v.device.type == dev for v in tr.sampler.sample(8).values())


def test_bf16_autocast_trains_on_the_cpu():
    """The path a GPU takes by default (train.autocast=auto is bf16 there), run on the CPU."""
    tr = _tiny_trainer("cpu", autocast="bf16", steps=80)
    res = tr.fit()
    assert res.bad_steps == 0 and tr.finite_state()
    losses = [h["total"] for h in res.history if "total" in h]
    fp32 = [h["total"] for h in _tiny_trainer("cpu", steps=80).fit().history if "total" in h]
    assert losses[-1] < 0.5 * losses[0] and losses[-1] < 1.2 * fp32[-1]  # learns, and as well as fp32


@pytest.mark.parametrize("native", [True, False])
@pytest.mark.parametrize("blur", ["on", "off"])
def test_auto_stays_fp32_on_the_cpu_and_names_bf16_where_it_pays(monkeypatch, native, blur):
    """bf16 is named where this CPU computes it natively and the model has a blur generator (its
    patches' products are where it is faster); auto itself stays fp32 on the CPU."""
    from layercam.engine import resolve as r

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    monkeypatch.setattr(r, "cpu_bf16", lambda: native)
    res = r.resolve(load_config("fast", [f"model.blur={blur}"]), frames=2, hw=(16, 16))
    assert res.settings.train.autocast == "none"
    assert ("train.autocast=bf16" in res.reasons["train.autocast"]) == (native and blur == "on")


def test_interrupted_and_resumed_training_ends_where_one_run_ends(tmp_path, monkeypatch):
    """Ctrl-C and the same command again give the model one uninterrupted run gives: the sparse grid
    levels' row-wise Adam state (moments, each row's last step) is saved and restored with the checkpoint."""
    from layercam.core import interrupts

    whole = _tiny_trainer("cpu", steps=30)
    whole.fit()
    first = _tiny_trainer("cpu", steps=30)
    first.ckpt_path = tmp_path / "ckpt.pt"
    monkeypatch.setenv(interrupts.ENV, "train:17:INT")  # Ctrl-C at step 17
    with pytest.raises(KeyboardInterrupt):
        first.fit()
    monkeypatch.delenv(interrupts.ENV)
    again = _tiny_trainer("cpu", steps=30)
    again.ckpt_path = tmp_path / "ckpt.pt"
    assert again.fit().resumed_from == 17
    for (name, a), b in zip(whole.model.state_dict().items(), again.model.state_dict().values()):
        assert torch.equal(a, b), name


def test_a_finished_trainings_checkpoint_keeps_the_model_not_the_optimiser(tmp_path, monkeypatch):
    """The last checkpoint of a finished training leaves Adam's moments out (under half the file on
    the tiny model: they are two more copies of the parameters); one taken mid-training keeps
    them. A training started again on it resumes at its end with the same model, and training on
    to more steps from it is one clear error."""
    from layercam.core import interrupts
    from layercam.core.errors import LayercamError

    mid = _tiny_trainer("cpu", steps=30)
    mid.ckpt_path = tmp_path / "mid.pt"
    monkeypatch.setenv(interrupts.ENV, "train:17:INT")
    with pytest.raises(KeyboardInterrupt):
        mid.fit()
    monkeypatch.delenv(interrupts.ENV)
    done = _tiny_trainer("cpu", steps=30)
    done.ckpt_path = tmp_path / "done.pt"
    done.fit()
    saved = torch.load(done.ckpt_path, map_location="cpu", weights_only=False)
    assert "opt" not in saved and saved["step"] == 30
    assert "opt" in torch.load(mid.ckpt_path, map_location="cpu", weights_only=False)
    assert done.ckpt_path.stat().st_size < 0.5 * mid.ckpt_path.stat().st_size
    again = _tiny_trainer("cpu", steps=30)
    again.ckpt_path = done.ckpt_path
    assert again.fit().resumed_from == 30
    for (name, a), b in zip(done.model.state_dict().items(), again.model.state_dict().values()):
        assert torch.equal(a, b), name
    more = _tiny_trainer("cpu", steps=40)
    more.ckpt_path = done.ckpt_path
    with pytest.raises(LayercamError, match="finished training's checkpoint"):
        more.fit()
