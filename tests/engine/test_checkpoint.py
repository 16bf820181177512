"""Checkpoints: a run saved now loads back the same model, with the settings it was resolved with
and the sizes derived for it; a run saved by an earlier version (format 1 or 2) is refused with one
clear line by ``render`` and ``edit``, nothing written."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from layercam.engine.checkpoint import FORMAT, load_run_model, save_run_model
from layercam.cli import main
from layercam.core.presets import load_config
from layercam.core.errors import LayercamError
from layercam.engine.model import ImplicitCameraModel

from conftest import decided, scaled_h0

OLD_RUN = Path(__file__).parents[1] / "data" / "run_format1"  # hdr-video, 2 layers + 3x3 blur (s =
                                                              # 2), 4 frames 16x16, made at 11fa359


def test_a_checkpoint_of_an_earlier_format_is_refused_with_one_line(tmp_path, capsys):
    raw = torch.load(OLD_RUN / "checkpoint.pt", weights_only=False)
    assert "spec" in raw and raw.get("format", 1) < FORMAT  # really an old format
    with pytest.raises(LayercamError, match="earlier layercam.*run the command that made the run again"):
        load_run_model(OLD_RUN)
    run = tmp_path / "run"
    shutil.copytree(OLD_RUN, run)
    before = sorted(p.relative_to(run) for p in run.rglob("*"))
    for argv in (["render", str(run), "--exposure", "1", "--quiet"],
                 ["edit", str(run), "--layer", "1", "--atlas", str(run / "atlases" / "layer1.png"),
                  "--quiet"]):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("error:") and "\n" not in err and "earlier layercam" in err
    assert sorted(p.relative_to(run) for p in run.rglob("*")) == before


def test_saved_run_keeps_its_settings_and_grid_sizes(tmp_path):
    """A run saved now stores the resolved settings and the sizes it was built with, and loads back
    the same model."""
    # no step cap: its floor sets the levels
    cfg = load_config("fast", ["scene.grid_levels=3", "train.passes_per_frame=0"])
    h0 = scaled_h0(0.8, frames=3)
    meta = {"h0": h0, "log2_dt": np.zeros(3), "exposure_learn": "none", "phase": None,
            "init_log2": 0.0, "frame_hw": (40, 40)}
    model = ImplicitCameraModel(decided(cfg, h0, (40, 40), blur="3x3"),
                                torch.as_tensor(h0, dtype=torch.float32), np.zeros(3),
                                frame_hw=(40, 40))
    grids = model.scene.atlases[0].enc.resolutions
    assert grids[-1] == 50
    # as written now
    (tmp_path / "new").mkdir()
    save_run_model(tmp_path / "new" / "checkpoint.pt", model, meta)
    ck = torch.load(tmp_path / "new" / "checkpoint.pt", weights_only=False)
    assert ck["format"] == FORMAT and ck["sizes"]["grid_max_res"] == 50 and ck["settings"]["scene"]["grid_levels"] == 3
    loaded, meta2 = load_run_model(tmp_path / "new")
    assert loaded.resolved == model.resolved and loaded.scene.atlases[0].enc.resolutions == grids
    for (k, v), (k2, v2) in zip(model.state_dict().items(), loaded.state_dict().items()):
        assert k == k2 and torch.equal(v, v2)
    xy = torch.rand(7, 2) * 2 - 1
    t = torch.zeros(7, dtype=torch.long)
    assert torch.allclose(loaded(xy, t)["rgb"], model.eval()(xy, t)["rgb"])
