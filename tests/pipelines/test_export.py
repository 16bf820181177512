"""The one export stage: each task's writers from the table; half floats only while the irradiance
fits them; nothing non-finite written. (psf.json from hdr-video with a blur generator: test_cli;
the same pixels from a model rebuilt from the cache: test_pipeline.)"""

from __future__ import annotations

import numpy as np
import pytest

from layercam.core.presets import load_config
from layercam.core.errors import LayercamError
from layercam.io import Clip, Exposures, read_exr
from layercam.pipelines.export import TASK_WRITERS, outputs_for, writers_for
from layercam.pipelines.tasks import run_task

from conftest import TINY


def test_every_task_has_its_writers_and_the_common_ones():
    for task in TASK_WRITERS:
        w = writers_for(task)
        assert {"crf", "psf", "atlases", "checkpoint"} <= set(w)
        assert len(w) == len(set(w))
    assert ("psf.json" in outputs_for("hdr-video") and "fused.exr" in outputs_for("fuse-stack")
            and "frames" in outputs_for("deblur-video"))


def _clip(frames):
    return Clip(frames=np.asarray(frames, np.float32), source="test", names=[str(i) for i in range(len(frames))])


def test_export_writes_float32_when_irradiance_exceeds_half(tmp_path):
    # white frames at exposures 2^-12: the irradiance starts near 2^21, beyond half floats
    ex = Exposures(np.array([-12.0, -11.0]), "none", np.array([0, 1]), "alt", "test")
    cfg = load_config("fast", TINY + ["train.steps=4", "train.batch=64"])
    ctx = run_task("hdr-video", _clip(np.ones((2, 8, 8, 3))), ex, cfg, tmp_path / "run", progress=False)
    assert ctx.results["export"].summary["exr"] == "float32"
    img = read_exr(tmp_path / "run" / "hdr" / "frame_00000.exr")
    assert np.isfinite(img).all() and img.max() > 65504


def test_export_refuses_non_finite_render(tiny_scene, tiny_exposures, tmp_path, monkeypatch):
    import layercam.scene.render as render

    real = render.render_frame

    def nan_render(*a, **k):
        out = real(*a, **k)
        for key in ("hdr", "log2_r"):  # the model alone, or corrected towards the frame (export.faithful)
            if out.get(key) is not None:
                out[key][0, 0, 0] = np.nan
        return out

    monkeypatch.setattr(render, "render_frame", nan_render)
    cfg = load_config("fast", TINY + ["train.steps=4"])
    with pytest.raises(LayercamError, match="non-finite irradiance"):
        run_task("hdr-video", tiny_scene.clip, tiny_exposures, cfg, tmp_path / "run", progress=False)
    assert not list((tmp_path / "run").glob("hdr/*.exr"))


def _run_flow(run):
    from layercam.vision import flow_store

    return flow_store.load(next((run / "cache").glob("flow-*")))


def _flow_arrays(fl) -> list[np.ndarray]:
    """The run's flow as ``flow_vote`` takes it: ``fw, bw`` float32, ``fw_ok, bw_ok`` bool, in memory."""
    return [np.asarray(fl[k][:], np.float32 if k in ("fw", "bw") else bool) for k in ("fw", "bw", "fw_ok", "bw_ok")]


def test_the_alpha_mattes_are_the_models_alpha_voted_along_the_flow_and_feathered(two_layer_run):
    """``alpha/frame_*.png`` hold the model's alpha voted with its neighbours' along the run's flow
    (``flow_vote``, ``VOTE_REACH`` either side), then (> 0.5) through the guided filter with the input
    frame as the guide (``guided_matte``), to the PNG's precision; the model's own alpha is not it."""
    from layercam.engine.checkpoint import load_run_model
    from layercam.io import read_image
    from layercam.scene.render import render_frame
    from layercam.vision.motion import flow_vote
    from layercam.vision.segment.edges import VOTE_REACH, guided_matte

    run, frames = two_layer_run["run"], two_layer_run["scene"].clip.frames
    model, _ = load_run_model(run)
    flows = _flow_arrays(_run_flow(run))
    alphas = [render_frame(model, t, frames.shape[1:3], ("alpha",))["alpha"] for t in range(len(frames))]
    for t in (0, len(frames) // 2, len(frames) - 1):
        a = flow_vote(alphas, t, *flows, reach=VOTE_REACH)
        assert (a > 0.5).any()
        got = read_image(run / "alpha" / f"frame_{t:05d}.png")[..., 0]
        assert np.abs(got - guided_matte(np.asarray(frames[t], np.float32), a)).max() < 1.5 / 255, t
        assert np.abs(got - alphas[t]).max() > 4 / 255, t


def test_the_atlas_sink_votes_each_matte_holding_only_the_alpha_its_reach_needs(two_layer_run, tmp_path):
    """The sink writes a matte once the frames its vote reads have arrived, and forgets alpha no later
    matte reads: at reach 1 it keeps two frames' alpha between frames, and each matte is ``flow_vote`` at
    that reach through the guided filter."""
    from layercam.engine.checkpoint import load_run_model
    from layercam.io import read_image
    from layercam.pipelines.atlas_export import AtlasSink
    from layercam.scene.render import render_frame
    from layercam.vision.motion import flow_vote
    from layercam.vision.segment.edges import guided_matte

    run, frames = two_layer_run["run"], two_layer_run["scene"].clip.frames
    model, _ = load_run_model(run)
    fl = _run_flow(run)
    sink = AtlasSink(model, tmp_path, frames, flow=fl)
    sink.reach = 1
    alphas, held = [], []
    for t in range(len(frames)):
        m = render_frame(model, t, frames.shape[1:3], ("uv", "alpha"))
        alphas.append(m["alpha"])
        sink.add(t, m["uv"], m["alpha"])
        held.append(len(sink.alphas))
    sink.close()
    assert max(held) == 2 and len(list((tmp_path / "alpha").glob("*.png"))) == len(frames)
    flows = _flow_arrays(fl)
    for t in range(len(frames)):
        want = guided_matte(np.asarray(frames[t], np.float32), flow_vote(alphas, t, *flows, reach=1))
        assert np.abs(read_image(tmp_path / "alpha" / f"frame_{t:05d}.png")[..., 0] - want).max() < 1.5 / 255, t


def test_atlases_fed_by_the_hdr_frames_match_the_atlases_rendered_alone(two_layer_run, tmp_path):
    """hdr-video's export hands each frame's geometry from its HDR render to the atlases
    (``AtlasSink``): the same files as rendering the geometry for the atlases alone; a frame out of
    order is refused."""
    import cv2

    from layercam.engine.checkpoint import load_run_model
    from layercam.pipelines.atlas_export import AtlasSink, export_atlases

    run, frames = two_layer_run["run"], two_layer_run["scene"].clip.frames
    model, ck = load_run_model(run)
    summary = export_atlases(model, tmp_path, frames, fps=float(ck.get("fps") or 24.0), flow=_run_flow(run))
    assert summary["alpha_mattes"] == len(frames) == len(list((run / "alpha").glob("*.png")))
    for name in ("alpha/frame_00000.png", f"alpha/frame_{len(frames) - 1:05d}.png", "atlases/layer1.png"):
        assert np.array_equal(cv2.imread(str(run / name), cv2.IMREAD_UNCHANGED),
                              cv2.imread(str(tmp_path / name), cv2.IMREAD_UNCHANGED)), name
    for k in (0, 1):
        assert np.array_equal(read_exr(run / "atlases" / f"layer{k}.exr"),
                              read_exr(tmp_path / "atlases" / f"layer{k}.exr"))
    sink = AtlasSink(model, tmp_path / "again", frames)
    with pytest.raises(ValueError, match="frame 1 where frame 0 was due"):
        try:
            sink.add(1, [np.zeros((*frames.shape[1:3], 2), np.float32)] * 2, np.zeros(frames.shape[1:3], np.float32))
        except ValueError:
            sink.abort()
            raise
    assert not list((tmp_path / "again" / "atlases").glob("*.mp4"))  # the videos begun were dropped
