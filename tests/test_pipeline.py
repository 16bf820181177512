"""End to end on tiny clips: the stage cache skips, invalidates and resumes; outputs are sane."""

from __future__ import annotations

import json

import numpy as np
import pytest

from layercam.config import load_config
from layercam.io import read_exr
from layercam.pipelines.tasks import run_task

from conftest import TINY


def _run(scene, exposures, out, extra=()):
    cfg = load_config("fast", TINY + list(extra))
    return run_task("hdr-video", scene.clip, exposures, cfg, out, progress=False)


def test_end_to_end_outputs_and_loss_falls(tiny_scene, tiny_exposures, tmp_path):
    ctx = _run(tiny_scene, tiny_exposures, tmp_path / "run")
    run = tmp_path / "run"
    for name in ["preview.mp4", "crf.json", "crf.png", "report.json", "checkpoint.pt"]:
        assert (run / name).is_file(), name
    exrs = sorted((run / "hdr").glob("frame_*.exr"))
    assert len(exrs) == tiny_scene.clip.T
    for p in exrs:
        img = read_exr(p)
        assert img.shape == (32, 32, 3)
        assert np.isfinite(img).all() and (img >= 0).all()
    rep = json.loads((run / "report.json").read_text())
    tr = rep["train"]
    assert tr["final_loss"]["color"] < 0.5 * tr["first_loss"]["color"]
    assert rep["analysis"]["layers"] == 1 and rep["analysis"]["tone_mapper"] == "learned"
    crf = json.loads((run / "crf.json").read_text())
    assert len(crf["r"]) == len(crf["z_stops"])


def test_same_command_skips_changed_setting_redoes_dependents(tiny_scene, tiny_exposures, tmp_path):
    run = tmp_path / "run"
    _run(tiny_scene, tiny_exposures, run)
    ctx = _run(tiny_scene, tiny_exposures, run)
    assert all(t["cached"] for t in ctx.times.values())
    ctx = _run(tiny_scene, tiny_exposures, run, ["train.steps=70"])
    assert ctx.times["flow"]["cached"] and ctx.times["bootstrap"]["cached"]
    assert not ctx.times["train"]["cached"] and not ctx.times["export"]["cached"]
    # the earlier export was set aside, not overwritten
    prev = list((run / "previous").glob("*/report.json"))
    assert prev, "earlier outputs should be kept under previous/"
    ctx = _run(tiny_scene, tiny_exposures, run, ["flow.method=dis_medium"])
    assert not ctx.times["flow"]["cached"] and not ctx.times["train"]["cached"]


def test_interrupted_training_resumes(tiny_scene, tiny_exposures, tmp_path, monkeypatch):
    from layercam import train as train_mod

    run = tmp_path / "run"
    calls = {"n": 0}
    real = train_mod.Trainer._set_lr

    def interrupt_at_45(self):
        calls["n"] += 1
        if self.step == 45:
            raise KeyboardInterrupt
        return real(self)

    monkeypatch.setattr(train_mod.Trainer, "_set_lr", interrupt_at_45)
    with pytest.raises(KeyboardInterrupt):
        _run(tiny_scene, tiny_exposures, run)
    monkeypatch.setattr(train_mod.Trainer, "_set_lr", real)
    ckpts = list((run / "cache").glob("train-*/ckpt.pt"))
    assert len(ckpts) == 1
    ctx = _run(tiny_scene, tiny_exposures, run)
    assert ctx.results["train"]["resumed_from"] == 45
    assert ctx.results["train"]["steps"] == 60
    assert ctx.times["flow"]["cached"]


def test_foreign_files_in_run_folder_are_not_overwritten(tiny_scene, tiny_exposures, tmp_path):
    from layercam.errors import LayercamError

    run = tmp_path / "run"
    run.mkdir()
    (run / "preview.mp4").write_bytes(b"somebody else's video")
    with pytest.raises(LayercamError):
        _run(tiny_scene, tiny_exposures, run)
    assert (run / "preview.mp4").read_bytes() == b"somebody else's video"
