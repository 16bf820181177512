"""Checkpoints: a run saved by an earlier version (format 1: the model's choices in a separate
``spec`` dict) still loads, renders the same pixels, and takes ``layercam render`` and ``edit``."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import torch

from layercam.checkpoint import FORMAT, load_run_model, save_run_model
from layercam.cli import main
from layercam.config import load_config
from layercam.model import ImplicitCameraModel
from layercam.render import render_frame

from conftest import decided, scaled_h0

OLD_RUN = Path(__file__).parent / "data" / "run_format1"  # hdr-video, 2 layers + 3x3 blur (s = 2), 4 frames 16x16, made at 11fa359


def test_format1_checkpoint_renders_what_it_rendered_then():
    raw = torch.load(OLD_RUN / "checkpoint.pt", weights_only=False)
    assert "spec" in raw and "model" not in raw["cfg"]  # really the old format
    model, meta = load_run_model(OLD_RUN)
    assert meta["format"] == FORMAT and meta["reasons"]["layers"] == "forced by --layers"
    m, b = model.cfg.model, model.cfg.blur
    assert (m.layers, m.tone_mapper, m.blur, b.n, b.max_offset, m.flow_loss) == (2, "learned", "on", 3, 2.0, True)
    expected = np.load(OLD_RUN / "expected.npz")
    out = render_frame(model, 1, (16, 16), ("hdr", "alpha", "ldr"))
    # the grids are now tables read through a channels-last view: float32 rounding may differ in the last bit
    np.testing.assert_allclose(out["hdr"], expected["hdr"], rtol=1e-6, atol=0)
    np.testing.assert_array_equal(out["alpha"], expected["alpha"])
    np.testing.assert_allclose(out["ldr"], expected["ldr"], rtol=1e-6, atol=0)


def test_format1_run_takes_render_and_edit(tmp_path):
    run = tmp_path / "run"
    shutil.copytree(OLD_RUN, run)
    assert main(["render", str(run), "--exposure", "1", "--quiet"]) == 0
    assert len(list((run / "render" / "exposure_+1.00").glob("frame_*.png"))) == 4
    assert main(["render", str(run), "--focus", "0.5", "--quiet"]) == 0  # the blur generator of format 1
    import cv2

    png = cv2.imread(str(run / "atlases" / "layer1.png"), cv2.IMREAD_UNCHANGED)
    png[8:24, 8:24, :3] = (0, 0, 255)  # paint a red square on the foreground's atlas
    cv2.imwrite(str(tmp_path / "edited.png"), png)
    assert main(["edit", str(run), "--layer", "1", "--atlas", str(tmp_path / "edited.png"), "--quiet"]) == 0
    assert len(list((run / "edit" / "hdr").glob("*.exr"))) == 4


def test_saved_now_loads_back_the_same(tmp_path):
    model, meta = load_run_model(OLD_RUN)
    save_run_model(tmp_path / "checkpoint.pt", model, meta)
    again, meta2 = load_run_model(tmp_path)
    assert meta2["cfg"] == model.cfg.to_dict() and "spec" not in meta2
    for (k, v), (k2, v2) in zip(model.state_dict().items(), again.state_dict().items()):
        assert k == k2 and torch.equal(v, v2)


def test_saved_run_keeps_its_grid_sizes(tmp_path):
    """A run saved with the derived sizes left at 0 (older runs) is rebuilt from its saved grids;
    a run saved now stores the sizes it was built with."""
    cfg = load_config("fast", ["scene.grid_levels=3", "train.passes_per_frame=0"])  # no step cap: its floor sets the levels
    h0 = scaled_h0(0.8, frames=3)
    meta = {"h0": h0, "log2_dt": np.zeros(3), "exposure_learn": "none", "phase": None, "init_log2": 0.0, "frame_hw": (40, 40)}
    model = ImplicitCameraModel(decided(cfg, h0, (40, 40), blur="3x3"), torch.as_tensor(h0, dtype=torch.float32), np.zeros(3), frame_hw=(40, 40))
    grids = model.scene.atlases[0].enc.resolutions
    assert grids[-1] == 50
    # as an older version wrote it: cfg with grid_max_res = 0 and the model chosen in a "spec"
    spec = {"layers": 1, "tone_mapper": "learned", "exposures": "given", "blur": "3x3", "max_offset": 5.0, "flow_loss": True, "reasons": {}}
    enc = model.scene.atlases[0].enc  # and the grids as it stored them: one (1, F, r, r) image per level
    state = {k: v for k, v in model.state_dict().items() if ".enc.levels." not in k}
    state.update({f"scene.atlases.0.enc.grids.{l}": enc.level_grid(l)[None].detach().clone() for l in range(len(grids))})
    torch.save({"state": state, "cfg": {k: v for k, v in cfg.to_dict().items() if k != "model"}, "spec": spec, **meta}, tmp_path / "checkpoint.pt")
    loaded, _ = load_run_model(tmp_path)
    assert loaded.scene.atlases[0].enc.resolutions == grids
    # as written now
    (tmp_path / "new").mkdir()
    save_run_model(tmp_path / "new" / "checkpoint.pt", model, meta)
    ck = torch.load(tmp_path / "new" / "checkpoint.pt", weights_only=False)
    assert ck["cfg"]["scene"]["grid_max_res"] == 50
    loaded, _ = load_run_model(tmp_path / "new")
    xy = torch.rand(7, 2) * 2 - 1
    t = torch.zeros(7, dtype=torch.long)
    assert torch.allclose(loaded(xy, t)["rgb"], model.eval()(xy, t)["rgb"])
