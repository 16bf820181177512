"""The one export stage: each task's writers from the table, psf.json wherever there is a blur
generator, and the same pixels from a model trained in this run or rebuilt from the cache."""

from __future__ import annotations

import json

import numpy as np

from layercam.cli import main
from layercam.config import load_config
from layercam.io import read_exr
from layercam.pipelines.export import TASK_WRITERS, outputs_for, writers_for
from layercam.pipelines.tasks import run_task

from conftest import SMALL_BLUR, TINY


def test_every_task_has_its_writers_and_the_common_ones():
    for task in TASK_WRITERS:
        w = writers_for(task)
        assert {"crf", "psf", "atlases", "checkpoint"} <= set(w)
        assert len(w) == len(set(w))
    assert "psf.json" in outputs_for("hdr-video") and "fused.exr" in outputs_for("fuse-stack") and "frames" in outputs_for("deblur-video")


def test_hdr_video_with_a_blur_generator_writes_psf_json(tmp_path, tiny_scene):
    from layercam.io import write_video

    video = tmp_path / "clip.mp4"
    write_video(video, tiny_scene.clip.frames, fps=8)
    argv = ["hdr-video", str(video), "--exposures", "alt", "--ev-step", "3", "--blur", "3x3", "--out", str(tmp_path / "run"), "--preset", "fast", "--quiet"]
    for s in TINY + SMALL_BLUR + ["train.steps=20"]:
        argv += ["--set", s]
    assert main(argv) == 0
    psf = json.loads((tmp_path / "run" / "psf.json").read_text())
    assert len(psf["spread_px"]) == len(psf["frames"]) == tiny_scene.clip.T
    rep = json.loads((tmp_path / "run" / "report.json").read_text())
    assert rep["analysis"]["blur"] == "3x3" and rep["export"]["psf"]["spread_px"] == psf["spread_px"]
    assert (tmp_path / "run" / "atlases" / "atlas.json").is_file() and len(list((tmp_path / "run" / "hdr").glob("*.exr"))) == tiny_scene.clip.T


def test_model_rebuilt_from_the_cache_exports_the_same_pixels(tiny_scene, tiny_exposures, tmp_path):
    """A cached training is rebuilt from its last checkpoint: its export equals the export of the
    model as it left training in another run."""
    tiny = TINY + ["train.steps=20"]
    run_task("hdr-video", tiny_scene.clip, tiny_exposures, load_config("fast", tiny), tmp_path / "a", progress=False)
    ctx = run_task("hdr-video", tiny_scene.clip, tiny_exposures, load_config("fast", tiny + ["export.half=off"]), tmp_path / "a", progress=False)
    assert ctx.times["train"]["cached"] and not ctx.times["export"]["cached"]
    run_task("hdr-video", tiny_scene.clip, tiny_exposures, load_config("fast", tiny + ["export.half=off"]), tmp_path / "b", progress=False)
    for t in range(tiny_scene.clip.T):
        np.testing.assert_array_equal(read_exr(tmp_path / "a" / "hdr" / f"frame_{t:05d}.exr"), read_exr(tmp_path / "b" / "hdr" / f"frame_{t:05d}.exr"))
