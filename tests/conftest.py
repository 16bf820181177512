"""Shared fixtures: tiny synthetic clips and a tiny preset so that end-to-end runs take seconds."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

# the shared captures: $LAYERCAM_DATA (as `layercam bench --suite real` reads it), else beside the checkout
SHARED_DATA = Path(os.environ.get("LAYERCAM_DATA") or Path(__file__).resolve().parents[2] / "shared" / "data")

# Tests use tiny tensors: one thread is as fast, and it does not collapse when the machine is
# oversubscribed (OpenMP spin-waits made 2-thread runs 10-20x slower on a loaded 2-core box).
os.environ.setdefault("OMP_NUM_THREADS", "1")
try:
    import torch

    torch.set_num_threads(1)
except ImportError:  # pragma: no cover
    pass

# A shell that starts the suite in the background (`sh -c 'pytest ...' &`) starts it with SIGINT
# ignored, and Python then installs no KeyboardInterrupt handler: the Ctrl-C tests
# (test_interruption, test_edit), which signal their own process, would see nothing happen.
import signal  # noqa: E402

if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

# settings that make any preset train in a second or two on a 16x16..32x32 clip
TINY = [
    "train.steps=60",
    "train.batch=512",
    "train.bootstrap_steps=10",
    "train.checkpoint_every=20",
    "scene.grid_levels=3",
    "scene.atlas_width=16",
    "scene.deform_width=16",
    "tone.width=16",
    "flow.method=dis_fast",
]
# ... and a small blur generator
SMALL_BLUR: list[str] = []  # the blur generator's nets have the paper's fixed size (camera.blur)


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.exists():
        pytest.skip(f"shared captures not found at {SHARED_DATA} (they live beside the checkout)")
    return SHARED_DATA


@pytest.fixture
def tiny_scene():
    from layercam import synth

    return synth.pan_hdr(frames=4, size=(32, 32), ev_step=3.0, seed=1)


@pytest.fixture
def tiny_exposures(tiny_scene):
    from layercam.io import Exposures

    log2 = np.log2(tiny_scene.exposure_times / tiny_scene.exposure_times.min())
    return Exposures(log2, "none", (np.arange(len(log2)) % 2), "alt", "test: known")


@pytest.fixture(scope="session")
def two_layer_run(tmp_path_factory):
    """A tiny two-layer hdr-video run on ``synth.moving_object`` (48x48, 6 frames) with the foreground
    found by motion segmentation (no masks given); shared by tests/test_layers.py and test_edit.py."""
    from layercam import synth
    from layercam.core.presets import load_config
    from layercam.io import Exposures
    from layercam.pipelines.tasks import run_task

    scene = synth.moving_object(frames=6, size=(48, 48), seed=0, object_radius=0.25)
    log2 = np.log2(scene.exposure_times / scene.exposure_times.min())
    exposures = Exposures(log2, "none", (np.arange(len(log2)) % 2), "alt", "test: known")
    run = tmp_path_factory.mktemp("layers") / "run"
    cfg = load_config("fast", TINY + ["train.steps=120", "train.bootstrap_steps=50", "model.layers=2"])
    ctx = run_task("hdr-video", scene.clip, exposures, cfg, run, progress=False)
    return {"scene": scene, "run": run, "ctx": ctx, "exposures": exposures, "cfg": cfg}


def decided(cfg=None, h0=None, frame_hw=(16, 16), static: bool = False, *, layers=1,
            tone_mapper="learned", exposures="given", blur="off", max_offset=5.0, flow_loss=True):
    """``cfg`` (default: the fast preset) with the model chosen by hand, as the analysis would write
    it, resolved (:func:`layercam.engine.resolve.resolve`) for a clip of the bootstrap mappings' ``h0 (L, T,
    3, 3)`` frames (default: identity, one per layer, 2 frames) of size ``frame_hw``, the camera
    ``static`` or not: ready for ``ImplicitCameraModel``."""
    import dataclasses

    from layercam.core.presets import load_config, model_overrides
    from layercam.engine.resolve import resolve

    cfg = (load_config("fast") if cfg is None else cfg).copy()
    for item in model_overrides(layers, tone_mapper, blur, max_offset, flow_loss) + [f"model.exposures={exposures}"]:
        cfg.set(*item.split("=", 1))
    h0 = np.tile(np.eye(3)[None, None], (layers, 2, 1, 1)) if h0 is None else h0
    r = resolve(cfg, frames=np.asarray(h0).shape[1], hw=frame_hw)
    return dataclasses.replace(r, static=static) if static else r


def scaled_h0(scale: float, frames: int = 2) -> np.ndarray:
    """One layer's identity mappings shrunk by ``scale`` ``(1, frames, 3, 3)``: the frame covers
    ``scale`` of the atlas."""
    return np.tile(np.diag([scale, scale, 1.0])[None, None], (1, frames, 1, 1))


def tiny_argv(command: str, inp, out, *extra: str) -> list[str]:
    """A CLI command line on a tiny clip with the TINY settings."""
    argv = [command, str(inp), "--out", str(out), "--preset", "fast", "--quiet", *extra]
    for s in TINY:
        argv += ["--set", s]
    return argv


@pytest.fixture(scope="session")
def tiny_frames(tmp_path_factory):
    """``tiny_scene``'s frames as a folder of PNGs (a CLI input): 4 frames 32x32, alternating 3 EV."""
    from layercam import synth
    from layercam.io import write_png

    folder = tmp_path_factory.mktemp("clip") / "frames"
    folder.mkdir()
    for t, f in enumerate(synth.pan_hdr(frames=4, size=(32, 32), ev_step=3.0, seed=1).clip.frames):
        write_png(folder / f"frame_{t:03d}.png", f)
    return folder
