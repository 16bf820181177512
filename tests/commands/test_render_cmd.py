"""``layercam render``: exposure re-renders and sweeps (monotone per pixel), focus interpolation
between training images through the blur generator, and refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest

from layercam.cli import main
from layercam.io import read_image

from conftest import SMALL_BLUR, TINY

@pytest.fixture(scope="module")
def stack_run(tmp_path_factory):
    """A tiny fuse-stack run on 3 images of a multi-focus multi-exposure stack (one per focus,
    each at another exposure): learned tone mapper and a blur generator."""
    from layercam import synth
    from layercam.core.presets import load_config
    from layercam.io import Exposures
    from layercam.io.clip import Clip
    from layercam.pipelines.tasks import run_task

    sc = synth.mfme_stack(size=(24, 24), focus_settings=3, exposures_ev=(0.0, 1.5, 3.0), planes=3, seed=4)
    idx = [0, 4, 8]
    clip = Clip(sc.clip.frames[idx], "synthetic:mfme_stack", [sc.clip.names[i] for i in idx])
    ev = sc.meta["ev"][idx]
    e = Exposures(ev - ev.min(), "none", None, "times", "test: known")
    run = tmp_path_factory.mktemp("render") / "run"
    run_task("fuse-stack", clip, e,
             load_config("fast", TINY + SMALL_BLUR + ["train.steps=80", "model.blur=on"]), run,
             progress=False)  # 24 px: too small for the analysis to compare sharpness
    return run, clip


def _load(run):
    from layercam.engine.checkpoint import load_run_model

    return load_run_model(run)


def test_exposure_sweep_is_monotone_per_pixel(stack_run):
    from layercam.scene.render import exposure_sweep

    run, _ = stack_run
    model, meta = _load(run)
    evs = np.linspace(-4, 4, 9)
    imgs = exposure_sweep(model, meta, evs, frame=1)
    assert imgs.shape == (9, 24, 24, 3) and np.isfinite(imgs).all()
    assert (np.diff(imgs, axis=0) >= -1e-3).all(), float(np.diff(imgs, axis=0).min())
    assert imgs[-1].mean() > imgs[0].mean() + 0.3  # it really brightens


def test_render_exposure_cli_writes_every_frame_and_refuses_overwrite(stack_run, capsys):
    run, clip = stack_run
    assert main(["render", str(run), "--exposure", "1", "--quiet"]) == 0
    folder = run / "render" / "exposure_+1.00"
    pngs = sorted(folder.glob("frame_*.png"))
    assert len(pngs) == clip.T and (folder / "video.mp4").is_file()
    info = json.loads((folder / "render.json").read_text())
    assert info["ev"] == 1.0
    brighter = np.stack([read_image(p) for p in pngs])
    assert main(["render", str(run), "--exposure", "-1", "--quiet"]) == 0
    darker = np.stack([read_image(p) for p in sorted((run / "render" / "exposure_-1.00").glob("*.png"))])
    assert (brighter >= darker).all() and brighter.mean() > darker.mean() + 0.05
    assert main(["render", str(run), "--exposure", "1", "--quiet"]) == 2  # finished outputs are kept
    assert "exists" in capsys.readouterr().err
    assert main(["render", str(run), "--exposure", "1", "--quiet", "--overwrite"]) == 0


def test_focus_interpolation_between_training_images(stack_run):
    """At integer F the blur generator gives the training image's own camera (its blur and exposure);
    between two indices the render moves smoothly from one to the other."""
    import torch

    from layercam.scene.render import exposure_at, focus_sweep
    from layercam.scene.coords import pixel_grid

    run, clip = stack_run
    model, meta = _load(run)
    view = 1
    fs = np.linspace(0.0, 1.0, 11)
    imgs = focus_sweep(model, meta, fs, frame=view)
    # endpoints are the model's camera for images 0 and 1 seen from the view of image 1
    with torch.no_grad():
        xy = pixel_grid(24, 24)
        t = torch.full((xy.shape[0],), view, dtype=torch.long)
        out = model.scene(xy, t)
        for f, img in ((0, imgs[0]), (1, imgs[-1])):
            lr = model.blur(model.scene, xy, t, out, t_blur=torch.full((xy.shape[0],), float(f)))
            ref = model.tone_map(lr, torch.full_like(lr[:, :1], exposure_at(model, f))).view(24, 24, 3).numpy()
            assert np.allclose(img, ref, atol=1e-5)
        cam = model(xy, t)["rgb"].view(24, 24, 3).numpy()  # image 1 through its own camera
    assert np.allclose(imgs[-1], cam, atol=1e-5)
    span = np.abs(imgs[-1] - imgs[0]).mean()
    assert span > 1e-3  # the two images differ (exposure and blur)
    steps = np.abs(np.diff(imgs, axis=0)).mean(axis=(1, 2, 3))
    assert steps.max() < 0.5 * span  # no jump: the interpolation is gradual
    mid = np.abs(imgs[5] - imgs[0]).mean()
    assert 0.2 * span < mid < 0.8 * span


def test_render_focus_and_sweep_cli(stack_run):
    run, clip = stack_run
    out = run.parent / "renders"
    assert main(["render", str(run), "--focus", "0.5", "--out", str(out), "--quiet"]) == 0
    img = read_image(out / "focus_0.50.png")
    assert img.shape == (24, 24, 3)
    assert json.loads((out / "focus_0.50.json").read_text())["view"] == 1  # the fused view
    assert main(["render", str(run), "--sweep", "focus", "--steps", "4", "--out", str(out), "--quiet"]) == 0
    assert len(list((out / "sweep_focus").glob("step_*.png"))) == 4 and (out / "sweep_focus.mp4").is_file()
    assert main(["render", str(run), "--sweep", "exposure", "--steps", "3", "--range=-2,2", "--out",
                 str(out), "--quiet"]) == 0
    assert len(list((out / "sweep_exposure").glob("step_*.png"))) == 3


@pytest.mark.parametrize("argv, needle",
                         [([], "nothing to render"), (["--focus", "5"], "--focus"),
                          (["--exposure", "99"], "exposure"),
                          (["--sweep", "focus", "--range", "0,x"], "range")])
def test_render_refusals(stack_run, capsys, argv, needle):
    run, _ = stack_run
    assert main(["render", str(run), "--quiet", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and needle in err


def test_render_needs_a_run(tmp_path, capsys):
    assert main(["render", str(tmp_path), "--exposure", "1"]) == 2
    assert "checkpoint.pt" in capsys.readouterr().err


def test_interrupted_render_is_redone_by_the_same_command(stack_run, tmp_path):
    """Issue 18 items 2 and 10: a render killed half-way (SIGKILL after two frames) leaves nothing
    under the final name, and the same command then writes the whole render; a folder of frames
    without render.json (an interrupted render of an older version) does not block it either."""
    import os
    import subprocess
    import sys

    run, clip = stack_run
    out, ref = tmp_path / "out", tmp_path / "ref"
    cmd = [sys.executable, "-m", "layercam", "render", str(run), "--exposure", "0.5", "--out", str(out), "--quiet"]
    r = subprocess.run(cmd, env=dict(os.environ, LAYERCAM_SIGNAL_AT="render:2:KILL"),
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == -9, r.stderr[-2000:]
    assert not (out / "exposure_+0.50").exists() and list(out.glob(".partial-*/exposure_+0.50/frame_*.png"))
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert main(["render", str(run), "--exposure", "0.5", "--out", str(ref), "--quiet"]) == 0
    got = sorted((out / "exposure_+0.50").iterdir())
    assert [p.name for p in got] == [p.name for p in sorted((ref / "exposure_+0.50").iterdir())]
    assert len([p for p in got if p.suffix == ".png"]) == clip.T and (out / "exposure_+0.50" / "render.json").is_file()
    for p in got:
        if p.suffix == ".png":
            assert np.array_equal(read_image(p), read_image(ref / "exposure_+0.50" / p.name))
    assert not list(out.glob(".partial-*"))


def test_render_left_without_its_sidecar_is_redone(stack_run, tmp_path):
    """Issue 18 item 2: frames without video.mp4 and render.json (what a render killed half-way
    left under its final name before renders were staged) do not block the same command."""
    run, clip = stack_run
    out = tmp_path / "out"
    assert main(["render", str(run), "--exposure", "0.5", "--out", str(out), "--quiet"]) == 0
    (out / "exposure_+0.50" / "render.json").unlink()
    (out / "exposure_+0.50" / "video.mp4").unlink()
    assert main(["render", str(run), "--exposure", "0.5", "--out", str(out), "--quiet"]) == 0
    assert (out / "exposure_+0.50" / "render.json").is_file() and (out / "exposure_+0.50" / "video.mp4").is_file()
    assert main(["render", str(run), "--exposure", "0.5", "--out", str(out), "--quiet"]) == 2  # finished: kept
