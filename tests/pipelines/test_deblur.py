"""``layercam deblur-video`` end to end on tiny synthetic shake clips, and the deblurring check."""

from __future__ import annotations

import json

import numpy as np
import pytest

from layercam.cli import main
from layercam.io import read_exr, read_image, write_png

from conftest import SMALL_BLUR, TINY

def _frames_folder(folder, frames):
    folder.mkdir()
    for t, f in enumerate(frames):
        write_png(folder / f"f{t:03d}.png", f)
    return folder


def _argv(inp, out, *extra):
    argv = ["deblur-video", str(inp), "--out", str(out), "--preset", "fast", "--quiet", *extra]
    for s in TINY + SMALL_BLUR:
        argv += ["--set", s]
    return argv


def test_deblur_video_single_exposure(tmp_path):
    from layercam import synth

    sc = synth.shake_blur(frames=4, size=(24, 24), max_blur_px=3.0, seed=1)
    inp = _frames_folder(tmp_path / "in", sc.clip.frames)
    run = tmp_path / "run"
    assert main(_argv(inp, run, "--blur", "3x3")) == 0  # forced: 24 px frames are too small to compare sharpness
    pngs = sorted((run / "frames").glob("frame_*.png"))
    assert [p.name for p in pngs] == [f"frame_{t:05d}.png" for t in range(4)]
    for t, p in enumerate(pngs):
        img = read_image(p)
        assert img.shape == (24, 24, 3)
        # the input's tonality: same overall brightness as the blurry frame it replaces
        assert abs(float(img.mean()) - float(sc.clip.frames[t].mean())) < 0.06
    assert (run / "deblurred.mp4").stat().st_size > 0
    assert not (run / "hdr").exists()  # one exposure: no HDR asked for
    rep = json.loads((run / "report.json").read_text())
    assert rep["task"] == "deblur-video" and rep["analysis"]["blur"] == "3x3"
    assert rep["analysis"]["tone_mapper"] == "fixed"
    assert rep["train"]["final_loss"]["color"] < rep["train"]["first_loss"]["color"]
    psf = json.loads((run / "psf.json").read_text())
    assert len(psf["spread_px"]) == 4
    # the same command again: everything cached, outputs kept
    assert main(_argv(inp, run, "--blur", "3x3")) == 0
    rep2 = json.loads((run / "report.json").read_text())
    assert all(s["cached"] for s in rep2["stages"].values())


def test_deblur_video_varying_exposure_writes_hdr(tmp_path):
    from layercam import synth

    sc = synth.shake_blur(frames=4, size=(24, 24), max_blur_px=3.0, exposures="alternating", ev_step=2.0, seed=2)
    inp = _frames_folder(tmp_path / "in", sc.clip.frames)
    run = tmp_path / "run"
    assert main(_argv(inp, run, "--exposures", "0,2", "--blur", "3x3")) == 0
    exrs = sorted((run / "hdr").glob("frame_*.exr"))
    assert len(exrs) == 4
    hdr = np.stack([read_exr(p) for p in exrs])
    assert np.isfinite(hdr).all() and (hdr > 0).all()
    # LDR frames keep each frame's exposure: the odd (brighter) frames stay brighter
    ldr = np.stack([read_image(run / "frames" / f"frame_{t:05d}.png") for t in range(4)])
    assert ldr[1].mean() > ldr[0].mean() and ldr[3].mean() > ldr[2].mean()
    assert json.loads((run / "report.json").read_text())["analysis"]["tone_mapper"] == "learned"


def test_a_frame_the_model_misses_is_written_from_the_input_and_its_mask_published(tmp_path, monkeypatch):
    import layercam.scene.render as render
    from layercam import synth

    sc = synth.shake_blur(frames=3, size=(32, 32), max_blur_px=2.0, seed=3)
    real = render.render_frame

    def frame_1_off(model, t, hw, what=("hdr",), **k):  # what a trained model should give, frame 1 in another view
        out = real(model, t, hw, what, **k)
        d = k.get("stride", 1)
        img = sc.clip.frames[t] if k.get("blur") else sc.sharp_ldr[t]  # re-blurred: the input itself where it holds
        out["ldr"] = np.asarray(np.roll(img, 10, axis=1) if t == 1 else img, np.float32)[::d, ::d].copy()
        return out

    monkeypatch.setattr(render, "render_frame", frame_1_off)
    inp = _frames_folder(tmp_path / "in", sc.clip.frames)
    run = tmp_path / "run"
    assert main(_argv(inp, run, "--blur", "3x3", "--set", "train.steps=4")) == 0
    rep = json.loads((run / "report.json").read_text())
    share = rep["export"]["trust"]["kept_share"]
    assert len(share) == 3 and share[1] < 0.1 and min(share[0], share[2]) > 0.9, share
    masks = [read_image(run / "trust" / f"frame_{t:05d}.png")[..., 0] for t in range(3)]  # published with the frames
    assert masks[1].max() < 0.3 and masks[0].min() > 0.8
    assert "trust" in json.loads((run / "outputs.json").read_text())["names"]
    out = [read_image(run / "frames" / f"frame_{t:05d}.png") for t in range(3)]
    moved = np.abs(np.roll(sc.sharp_ldr[1], 10, axis=1) - sc.clip.frames[1]).mean()
    # the input, not the frame in another view
    assert np.abs(out[1] - read_image(inp / "f001.png")).mean() < 0.1 * moved
    assert np.abs(out[0] - sc.sharp_ldr[0]).max() < 2.5 / 255  # the render, where it held


def test_single_frame_is_refused(tmp_path, capsys):
    inp = _frames_folder(tmp_path / "in", np.full((1, 16, 16, 3), 0.5, np.float32))
    assert main(_argv(inp, tmp_path / "run")) == 2
    assert "at least 2 frames" in capsys.readouterr().err


@pytest.mark.slow
def test_blur_generator_deblurs_shake_clip(tmp_path):
    """On a camera-shake clip the blur generator's sharp frames are closer to the sharp ground truth
    than the blurry input (shift-aligned PSNR), and so are the frames written (the render where its
    re-blur reproduces the input within the input's noise, pipelines/view.py); the learned PSF is
    wider where the blur is longer."""
    from layercam import synth
    from layercam.core.presets import load_config
    from layercam.io import Exposures
    from layercam.bench.evaluate import EvaluateStage
    from layercam.pipelines.tasks import run_task

    sc = synth.shake_blur(frames=6, size=(48, 48), max_blur_px=6.0, seed=0)
    e = Exposures(np.zeros(6), "none", None, "none", "single")
    # with a blur generator, at most one grid cell per pixel
    cfg = load_config("fast", ["train.batch=2048", "model.layers=1"])
    ctx = run_task("deblur-video", sc.clip, e, cfg, tmp_path / "run", progress=False, extra_stages=[EvaluateStage(sc)])
    from layercam.core.frame_metrics import score_frames
    from layercam.scene.render import render_frame

    res = ctx.results["evaluate"].summary["aligned"]
    sharp = np.stack([render_frame(ctx.model, t, (48, 48), "ldr")["ldr"] for t in range(6)])
    rendered = float(np.mean([r["psnr"] for r in score_frames(sharp, sc.sharp_ldr, 4, align=True)]))
    assert rendered > res["input"]["psnr"] + 1.0, (rendered, res)
    assert res["deblurred"]["psnr"] > res["input"]["psnr"] + 0.5, res
    spread = ctx.results["export"].summary["psf"]["spread_px"]
    assert np.corrcoef(spread, sc.meta["blur_length"])[0, 1] > 0.7
