"""The analysis chooses only what the scene needs, says why, and every choice can be forced."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from layercam import analyse, flow

from layercam.config import load_config, model_overrides, unresolved
from layercam.io import Clip, Exposures


def _flow(frames):
    fw, bw = flow.compute_flow(frames, method="dis_fast", progress=False)
    return {"fw": fw, "bw": bw, "fw_ok": flow.flow_consistency(fw, bw), "homs": flow.global_homographies(fw)}


def _texture(h, w, seed=0):
    import cv2

    rng = np.random.default_rng(seed)
    t = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 1.2)
    t = (t - t.min()) / (t.max() - t.min())
    return np.repeat(t[..., None] * 0.8 + 0.1, 3, axis=2)


def _single(t):
    return Exposures(np.zeros(t), "none", None, "none", "one exposure")


def _decide(frames, exposures=None, task="hdr-video", overrides=None):
    """``(the decided model as the report shows it, with its reasons; the measures)``; ``overrides``:
    the model flags (``{"layers": 2, "blur": "5x5"}``)."""
    clip = Clip(frames.astype(np.float32), "test", [f"{i:05d}" for i in range(len(frames))])
    ex = exposures or _single(len(frames))
    m = analyse.measure(clip, ex, _flow(clip.frames))
    cfg, reasons = analyse.decide(load_config("fast", model_overrides(**(overrides or {}))), clip, ex, task, m)
    assert not [k for k in unresolved(cfg) if k.startswith("model.") or k in ("blur.n", "blur.max_offset")]
    return SimpleNamespace(**analyse.model_summary(cfg), reasons=reasons), m


def test_static_sharp_single_exposure_gets_the_minimal_model():
    tex = _texture(48, 48)
    spec, m = _decide(np.stack([tex] * 4))
    assert spec.layers == 1 and spec.tone_mapper == "fixed" and spec.blur == "off" and not spec.flow_loss
    assert all(spec.reasons[k] for k in ("layers", "tone_mapper", "blur", "flow_loss"))


def test_object_moving_on_its_own_gets_two_layers():
    bg = _texture(64, 64, 0)
    fg = _texture(16, 16, 1)[..., ::-1] * 0.5 + 0.5
    frames = []
    for t in range(5):
        f = np.roll(bg, t, axis=1).copy()  # the camera pans 1 px/frame
        y, x = 10 + 5 * t, 40 - 6 * t    # the square moves its own way
        f[y : y + 16, x : x + 16] = fg
        frames.append(f)
    spec, m = _decide(np.stack(frames))
    assert spec.layers == 2, m
    assert spec.flow_loss


def test_blurred_frames_get_a_blur_generator():
    import cv2

    tex = _texture(64, 64)
    frames = np.stack([tex, cv2.GaussianBlur(tex, (0, 0), 2.0), tex, cv2.GaussianBlur(tex, (0, 0), 1.5)])
    spec, m = _decide(frames)
    assert spec.blur in ("3x3", "5x5"), m["relative_blur_sigma"]
    assert 2 <= spec.max_offset <= 8


def test_two_exposures_learn_a_tone_mapper_and_flags_force_choices():
    tex = _texture(32, 32)
    frames = np.stack([tex, np.clip(tex * 4, 0, 1), tex, np.clip(tex * 4, 0, 1)])
    ex = Exposures(np.array([0, 2, 0, 2.0]), "none", np.array([0, 1, 0, 1]), "alt", "given")
    spec, _ = _decide(frames, ex)
    assert spec.tone_mapper == "learned"
    spec, _ = _decide(frames, ex, overrides={"layers": 2, "blur": "5x5", "tone_mapper": "fixed", "flow_loss": True})
    assert (spec.layers, spec.blur, spec.tone_mapper, spec.flow_loss) == (2, "5x5", "fixed", True)
    assert "forced" in spec.reasons["layers"]


def test_camera_shake_alone_keeps_one_layer():
    """Motion blur that changes from frame to frame puts flow errors on a few scattered pixels
    (up to 1.4% of a pair); that is not an object moving on its own."""
    from layercam import synth

    s = synth.shake_blur(frames=10, size=(96, 96), max_blur_px=8.0, seed=0)
    spec, m = _decide(s.clip.frames, task="deblur-video")
    assert spec.layers == 1, m
    assert spec.blur != "off"
