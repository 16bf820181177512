"""Two-layer scenes: the foreground found without a detector, alpha separating it, atlas outputs."""

from __future__ import annotations

import copy
import json
import shutil

import numpy as np
import torch

from layercam.core import metrics
from layercam.io import read_exr, read_image, read_video


def test_two_layer_run_separates_the_moving_object(two_layer_run):
    scene, run, ctx = two_layer_run["scene"], two_layer_run["run"], two_layer_run["ctx"]
    T = scene.clip.T
    rep = json.loads((run / "report.json").read_text())
    assert rep["analysis"]["layers"] == 2
    fl = rep["train"]["final_loss"]
    assert all(np.isfinite(v) for v in fl.values()) and rep["train"]["bad_steps"] == 0
    # no --masks: the bootstrap computed motion masks and kept them in its cache folder
    boot = ctx.dirs["bootstrap"]
    assert ctx.results["bootstrap"].motion_masks
    assert (boot / "masks.npz").is_file() and len(list((boot / "masks").glob("frame_*.png"))) == T
    for t in range(T):
        hdr = read_exr(run / "hdr" / f"frame_{t:05d}.exr")
        assert np.isfinite(hdr).all() and (hdr >= 0).all()
    # alpha mattes: one 8-bit PNG per frame, and they find the object
    mattes = sorted((run / "alpha").glob("frame_*.png"))
    assert len(mattes) == T
    ious = [metrics.iou(read_image(p)[..., 0] > 0.5, scene.fg_mask[t]) for t, p in enumerate(mattes)]
    assert np.mean(ious) > 0.5, ious
    # the report keeps the share of the frames alpha holds: the mattes' own, and the object's size
    share = rep["export"]["atlas"]["foreground_share"]
    # a pixel at most (8-bit rounding)
    assert abs(share
               - np.mean([np.mean(read_image(p)[..., 0] > 0.5)
                          for p in mattes])) <= 1.0 / scene.fg_mask[0].size
    assert 0.5 < share / scene.fg_mask.mean() < 2.0
    assert not any("faded" in w for w in rep["warnings"])


def test_a_foreground_that_faded_in_training_is_said(two_layer_run):
    """``faded_foreground``: alpha holding less than a quarter of its masks' area is a warning, with
    the way out for masks the tool made (not for masks the user gave); none where it holds them, or
    without the share or masks."""
    from types import SimpleNamespace

    from layercam.pipelines.results import BootstrapResult, ExportResult
    from layercam.pipelines.stages import FADED_SHARE, faded_foreground

    masks = np.zeros((4, 10, 10), np.float32)
    masks[:, :2, :2] = 1  # 4% of the frames
    def ctx(share, given=False, boot=masks):
        return SimpleNamespace(masks=masks if given else None,
                               results={"bootstrap": BootstrapResult(masks=boot),
                                        "export": ExportResult({"atlas": {} if share is None
            else {"foreground_share": share}})})
    faded = faded_foreground(ctx(0.001))
    assert "faded" in faded and "0.10%" in faded and "4.00%" in faded and "motion masks" in faded and "--masks" in faded
    given = faded_foreground(ctx(0.001, given=True))
    assert "given masks" in given and "--masks gives" not in given
    assert faded_foreground(ctx(FADED_SHARE * 0.04 * 1.01)) is None and faded_foreground(ctx(0.05)) is None
    assert faded_foreground(ctx(None)) is None and faded_foreground(ctx(0.0, boot=None)) is None
    assert faded_foreground(ctx(0.0, boot=np.zeros_like(masks))) is None  # masks that found nothing: nothing to lose


def test_atlas_outputs_per_layer(two_layer_run):
    run, T = two_layer_run["run"], two_layer_run["scene"].clip.T
    import cv2

    info = json.loads((run / "atlases" / "atlas.json").read_text())
    assert [e["layer"] for e in info["layers"]] == [0, 1]
    for e in info["layers"]:
        k, res = e["layer"], e["res"]
        exr = read_exr(run / "atlases" / f"layer{k}.exr")
        assert exr.shape == (res, res, 3) and np.isfinite(exr).all() and (exr > 0).all()
        png = cv2.imread(str(run / "atlases" / f"layer{k}.png"), cv2.IMREAD_UNCHANGED)
        assert png.shape == (res, res, 4)
        cov = png[..., 3] > 127
        assert 0.02 < cov.mean() < 1.0, (k, cov.mean())  # frames cover part of the atlas, not all of it
        for name in (f"layer{k}_uv.mp4", f"layer{k}_alpha.mp4"):
            frames, _ = read_video(run / "atlases" / name)
            assert len(frames) == T
    # the foreground atlas is covered where the object maps, i.e. much less than the background's
    assert info["layers"][1]["coverage"] < info["layers"][0]["coverage"]


def test_changed_export_setting_sets_earlier_atlases_aside(two_layer_run, tmp_path):
    from layercam.pipelines.tasks import run_task

    run = tmp_path / "run"
    shutil.copytree(two_layer_run["run"], run)
    old = json.loads((run / "outputs.json").read_text())
    cfg = copy.deepcopy(two_layer_run["cfg"])
    cfg.export.half = False
    ctx = run_task("hdr-video", two_layer_run["scene"].clip, two_layer_run["exposures"], cfg, run, progress=False)
    assert ctx.times["train"]["cached"] and not ctx.times["export"]["cached"]
    new = json.loads((run / "outputs.json").read_text())
    assert new["key"] != old["key"] and (run / "atlases" / "atlas.json").is_file()
    kept = run / "previous" / old["key"]
    assert (kept / "atlases" / "atlas.json").is_file() and (kept / "hdr").is_dir()
    assert json.loads((kept / "outputs.json").read_text())["key"] == old["key"]
    assert len(list(kept.glob("alpha/frame_*.png"))) == two_layer_run["scene"].clip.T


def test_one_layer_atlas_export_has_no_alpha(tmp_path):
    from layercam.core.presets import load_config
    from layercam.pipelines.atlas_export import export_atlases
    from layercam.engine.checkpoint import build_model

    from conftest import decided

    h0 = np.stack([np.stack([np.eye(3, dtype=np.float32) * [0.8, 0.8, 1]] * 3)])
    cfg = decided(load_config("fast", ["scene.grid_levels=2"]), h0, (16, 16), tone_mapper="fixed")
    model = build_model(cfg, {"h0": h0, "log2_dt": np.zeros(3, np.float32), "init_log2": -2.0, "frame_hw": (16, 16)})
    frames = np.random.default_rng(0).uniform(0, 1, (3, 16, 16, 3)).astype(np.float32)
    summary = export_atlases(model, tmp_path, frames, fps=10)
    assert [e["layer"] for e in summary["layers"]] == [0] and summary["alpha_mattes"] == 0
    assert (tmp_path / "atlases" / "layer0.exr").is_file() and (tmp_path / "atlases" / "layer0_uv.mp4").is_file()
    assert not (tmp_path / "alpha").exists() and not (tmp_path / "atlases" / "layer0_alpha.mp4").exists()
    # identity mapping scaled by 0.8: frames cover the middle 80% of the atlas
    cov = summary["layers"][0]["coverage"]
    assert 0.5 < cov < 0.8


def test_flow_loss_counts_each_layer_where_it_is_seen():
    from layercam.engine.model import ImplicitCameraModel

    ok = torch.tensor([True, True, False])
    alpha = torch.tensor([[0.0], [0.75], [1.0]])
    w = ImplicitCameraModel._layer_flow_weights({"alpha": alpha, "uv": [None, None]}, ok)
    assert torch.allclose(w[0], torch.tensor([1.0, 0.25, 0.0])) and torch.allclose(w[1], torch.tensor([0.0, 0.75, 0.0]))
    one = ImplicitCameraModel._layer_flow_weights({"alpha": None, "uv": [None]}, ok)
    assert len(one) == 1 and torch.equal(one[0], ok)


def test_a_segment_setting_changed_makes_the_masks_again(two_layer_run, tmp_path):
    """The bootstrap's key holds the segment settings: the same run folder made again with another
    one computes its masks again (stale masks are never reused)."""
    from layercam.pipelines.tasks import run_task

    scene, exposures = two_layer_run["scene"], two_layer_run["exposures"]
    run = tmp_path / "run"
    shutil.copytree(two_layer_run["run"], run)
    cfg = copy.deepcopy(two_layer_run["cfg"])
    cfg.segment.k_sigma = 3.0  # not the default
    ctx = run_task("hdr-video", scene.clip, exposures, cfg, run, progress=False)
    assert not ctx.times["bootstrap"]["cached"] and ctx.keys["bootstrap"] != two_layer_run["ctx"].keys["bootstrap"]
    assert ctx.keys["train"] != two_layer_run["ctx"].keys["train"]  # trained on the new masks
    material = json.loads((ctx.dirs["bootstrap"] / "settings.json").read_text())["settings"]
    assert material["segment"]["k_sigma"] == 3.0


def test_no_object_found_runs_one_layer_and_says_why(tmp_path, monkeypatch):
    """hdr-video without --layers on a clip whose flow shows independent motion: when the foreground
    finder's verdict is that its masks hold no consistent object, the run goes on with one layer,
    the finder's reason in the analysis; forced two layers keep them."""
    from conftest import TINY
    from layercam import synth
    from layercam.core.presets import load_config
    from layercam.io import Exposures
    from layercam.pipelines.tasks import run_task
    from layercam.vision.segment import verdict as verdict_module

    scene = synth.moving_object(frames=6, size=(48, 48), seed=0, object_radius=0.25)
    exposures = Exposures(np.zeros(6), "none", np.zeros(6, int), "none", "test")
    said = "the candidate masks jump between frames (test)"
    monkeypatch.setattr(verdict_module, "verdict", lambda *a,
                        **k: {"found": False, "reason": said, "consistency": 0.1, "contrast": 1.0})
    cfg = load_config("fast", TINY + ["train.steps=30", "train.bootstrap_steps=10"])
    ctx = run_task("hdr-video", scene.clip, exposures, cfg, tmp_path / "auto", progress=False)
    rep = json.loads((tmp_path / "auto" / "report.json").read_text())
    assert rep["analysis"]["layers"] == 1 and said in rep["analysis"]["reasons"]["model.layers"]
    assert ctx.results["bootstrap"].h0.shape[0] == 1 and not (tmp_path / "auto" / "alpha").exists()
    forced = run_task("hdr-video", scene.clip, exposures,
                      load_config("fast",
                                  TINY
                                  + ["train.steps=30", "train.bootstrap_steps=10",
                                     "model.layers=2"]), tmp_path / "two", progress=False)
    assert forced.resolved.settings.model.layers == 2 and forced.results["bootstrap"].verdict["found"] is False
