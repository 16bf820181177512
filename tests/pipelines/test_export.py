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
    assert "psf.json" in outputs_for("hdr-video") and "fused.exr" in outputs_for("fuse-stack") and "frames" in outputs_for("deblur-video")


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
