"""The analysis chooses only what the scene needs, says why, and every choice can be forced."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import torch

from layercam.engine import decide
from layercam.vision import analyse, flow
from layercam.engine.checkpoint import load_run_model
from layercam.core.config import AUTO
from layercam.core.presets import load_config, model_overrides
from layercam.core.geometry import atlas_pixels
from layercam.io import Clip, Exposures
from layercam.engine.model import ImplicitCameraModel

from conftest import decided, scaled_h0


def _flow(frames, method="dis_fast"):
    fw, bw = flow.compute_flow(frames, method=method, progress=False)
    return {"fw": fw, "bw": bw, **flow.pair_arrays(frames, fw, bw)}


def _texture(h, w, seed=0):
    import cv2

    rng = np.random.default_rng(seed)
    t = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 1.2)
    t = (t - t.min()) / (t.max() - t.min())
    return np.repeat(t[..., None] * 0.8 + 0.1, 3, axis=2)


def _single(t):
    return Exposures(np.zeros(t), "none", None, "none", "one exposure")


def _decide(frames, exposures=None, task="hdr-video", overrides=None, method="dis_fast"):
    """``(the decided model as the report shows it, with its reasons; the measures)``; ``overrides``:
    the model flags (``{"layers": 2, "blur": "5x5"}``)."""
    clip = Clip(frames.astype(np.float32), "test", [f"{i:05d}" for i in range(len(frames))])
    ex = exposures or _single(len(frames))
    m = analyse.measure(clip, ex, _flow(clip.frames, method))
    cfg, reasons = decide.decide(load_config("fast", model_overrides(**(overrides or {}))), clip, ex, task, m)
    assert AUTO not in list(vars(cfg.model).values()) + [cfg.blur.n, cfg.blur.max_offset]
    return SimpleNamespace(**decide.model_summary(cfg), reasons=reasons), m


def test_static_sharp_single_exposure_gets_the_minimal_model():
    tex = _texture(48, 48)
    spec, m = _decide(np.stack([tex] * 4))
    assert spec.layers == 1 and spec.tone_mapper == "fixed" and spec.blur == "off" and not spec.flow_loss
    assert all(spec.reasons[k] for k in ("layers", "tone_mapper", "blur", "flow_loss"))
    assert "equally sharp" in spec.reasons["blur"] and "exposure" not in spec.reasons["blur"]


def test_deblur_video_of_equally_sharp_frames_says_they_stay_as_sharp():
    """``deblur-video`` on frames that are all equally sharp (or equally blurred) has no blur
    generator to fit; the reason the user reads says the frames come out as sharp as they went in
    and how to force one (the Adobe240 triplet, whose blur is the same motion blur in each frame)."""
    tex = _texture(48, 48)
    spec, _ = _decide(np.stack([tex] * 4), task="deblur-video")
    assert (spec.blur == "off" and "as sharp as they went in" in spec.reasons["blur"]
            and "--blur 3x3" in spec.reasons["blur"])


def _panning_square(T: int, where) -> np.ndarray:
    """``T`` frames 64x64: a texture panning 1 px/frame and a 16 px square at ``where(t) = (y, x)``."""
    bg = _texture(64, 64, 0)
    fg = _texture(16, 16, 1)[..., ::-1] * 0.5 + 0.5
    frames = []
    for t in range(T):
        f = np.roll(bg, t, axis=1).copy()
        y, x = where(t)
        f[y : y + 16, x : x + 16] = fg
        frames.append(f)
    return np.stack(frames)


def test_object_moving_on_its_own_gets_two_layers():
    spec, m = _decide(_panning_square(5, lambda t: (10 + 5 * t, 40 - 6 * t)))  # the square moves its own way
    assert spec.layers == 2, m
    assert spec.flow_loss


def test_slow_object_gets_two_layers_from_pairs_eight_frames_apart():
    # drifts 0.5 px/frame against the pan
    spec, m = _decide(_panning_square(16, lambda t: (20, 24 + t - int(round(0.5 * t)))))
    assert m["independent_pairs"] < decide.IND_MOTION_PAIRS  # neighbours: too slow to tell
    assert spec.layers == 2 and m["moving_pairs_long"] >= decide.LONG_MIN_PAIRS, m
    assert "8 frames apart" in spec.reasons["layers"]
    still, m = _decide(np.stack([np.roll(_texture(64, 64, 0), t, axis=1) for t in range(16)]))  # a pan alone
    assert still.layers == 1 and m["moving_pairs_long"] == 0, m


def test_given_masks_mean_two_layers():
    clip = Clip(np.stack([_texture(16, 16)] * 3), "test", ["0", "1", "2"])
    cfg, reasons = decide.decide(load_config("fast"), clip, _single(3), "hdr-video", {"masks_given": True})
    assert cfg.model.layers == 2 and "masks" in reasons["layers"]


def test_blurred_frames_get_a_blur_generator():
    import cv2

    tex = _texture(64, 64)
    frames = np.stack([tex, cv2.GaussianBlur(tex, (0, 0), 2.0), tex, cv2.GaussianBlur(tex, (0, 0), 1.5)])
    spec, m = _decide(frames)
    assert spec.blur == "3x3", m["blur_tile_share"]  # the paper's patch: its offsets reach the blur
    assert 2 <= spec.max_offset <= 8
    wide = np.stack([tex, cv2.GaussianBlur(tex, (0, 0), 4.0), tex, cv2.GaussianBlur(tex, (0, 0), 4.0)])
    spec, m = _decide(wide)
    assert spec.blur == "3x3" and spec.max_offset == 8, (m["blur_tile_share"], m["max_blur_sigma"])


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


def _grid(r, h0, hw):
    return ImplicitCameraModel(r, torch.as_tensor(h0, dtype=torch.float32), np.zeros(h0.shape[1]),
                               frame_hw=hw).sizes["grid_max_res"]


def test_grid_no_finer_than_pixels_with_blur():
    cfg = load_config("fast")
    h0 = scaled_h0(0.9)
    px = atlas_pixels(h0, (64, 64))
    assert abs(px - 64 / 0.9) < 1e-6
    # power of two at or above 71.1 px: at least one cell per pixel
    assert _grid(decided(cfg, h0, (64, 64), blur="off"), h0, (64, 64)) == 128
    # the extent itself: at most one cell per pixel
    assert _grid(decided(cfg, h0, (64, 64), blur="3x3"), h0, (64, 64)) == 71
    assert _grid(decided(cfg, h0, (64, 64), static=True), h0, (64, 64)) == 71  # a static one-layer scene too
    m = ImplicitCameraModel(decided(cfg, h0, (64, 64), blur="3x3"),
                            torch.as_tensor(h0, dtype=torch.float32), np.zeros(2),
                            frame_hw=(64, 64))
    assert m.scene.atlases[0].enc.resolutions[-1] == 71


def test_static_stack_drops_the_residual_warp(tmp_path):
    """A static one-layer stack (the flow's homographies move no corner: ``Resolved.static``): the
    deformation is the per-frame homographies only and the PSFs are centred; the saved run rebuilds
    the same."""
    from layercam import synth
    from layercam.io import Exposures
    from layercam.pipelines.tasks import run_task

    from conftest import TINY

    # 96 px: at 64 px the DIS flow between the two focus settings is noisy enough that RANSAC fits a
    # 2.5 px zoom on some CPUs / OpenCV builds (seeds 2, 3 on an AMD EPYC with OpenCV 5.0 and 4.14)
    sc = synth.mfme_stack(size=(96, 96), focus_settings=2, exposures_ev=(0.0,), planes=2, seed=3)
    exp = Exposures(np.zeros(2), "none", None, "none", "single")
    cfg = load_config("fast", TINY + ["train.steps=20", "model.layers=1", "model.blur=on"])
    ctx = run_task("fuse-stack", sc.clip, exp, cfg, tmp_path / "run", progress=False)
    assert ctx.resolved.static is True and ctx.results["bootstrap"].static is True
    model, ck = load_run_model(tmp_path / "run")
    assert model.scene.deformations[0].residual is None and ck["settings"]["static"] is True
    assert model.blur.centre_exact
    disp, w = model.blur.kernels(torch.rand(50, 2) * 2 - 1, torch.randint(0, 2, (50,)))
    assert torch.allclose((w[:, :, None] * disp).sum(1), torch.zeros(50, 2), atol=1e-4)


def test_moving_clip_keeps_psf_shift_free(tmp_path):
    """A clip whose camera moves (a pan, not static): the PSFs' shift stays free, the residual kept."""
    from layercam import synth
    from layercam.io import Exposures
    from layercam.pipelines.tasks import run_task

    from conftest import TINY

    sc = synth.pan_hdr(frames=3, size=(48, 48), ev_step=0.0, seed=0)  # pans 1.5 to 3 px a frame
    cfg = load_config("fast", TINY + ["train.steps=10", "model.layers=1", "model.blur=on", "blur.n=3"])
    ctx = run_task("deblur-video", sc.clip, Exposures(np.zeros(3), "none", None, "none", "single"),
                   cfg, tmp_path / "run", progress=False)
    assert ctx.resolved.static is False and ctx.results["bootstrap"].static is False
    model, ck = load_run_model(tmp_path / "run")
    assert ck["settings"]["static"] is False and not model.blur.centre_exact
    assert model.scene.deformations[0].residual_scale > 0


def _bracket(tex, evs, noise=0.01, seed=0):
    """A static scene through a gamma camera at exposures ``evs`` (stops): noise before the curve,
    clipping, 8-bit quantisation."""
    rng = np.random.default_rng(seed)
    lin = (tex * 1.3) ** 2.2
    out = []
    for ev in evs:
        v = np.clip(lin * 2.0**ev + rng.normal(0, noise, lin.shape) * np.sqrt(lin * 2.0**ev + 1e-4), 0, 1) ** (1 / 2.2)
        out.append(np.round(v * 255) / 255)
    return np.stack(out).astype(np.float32)


def test_exposure_bracket_is_one_sharp_layer():
    """Three shots 3 stops apart of a static scene: noise in the dark one and clipping in the bright
    one are neither blur nor motion."""
    frames = _bracket(_texture(96, 96, 3), (-3.0, 0.0, 3.0))
    ex = Exposures(np.array([-3.0, 0.0, 3.0]), "none", None, "times", "given")
    spec, m = _decide(frames, ex, task="fuse-stack", method="dis_medium")
    assert spec.layers == 1 and spec.blur == "off", (m, spec.reasons)
    assert "exposure, not focus" in spec.reasons["blur"] or "enough texture" in spec.reasons["blur"]


def test_robust_colour_loss_only_for_an_exposure_bracket():
    """``loss.robust = auto``: the Cauchy scale for a stack without a blur generator (its shots come
    from different moments), MSE for a focus stack (its PSFs are fitted by the errors at edges) and
    for videos; a value given is kept."""
    from layercam.vision import analyse

    frames = _bracket(_texture(64, 64, 3), (-2.0, 0.0, 2.0))
    ex = Exposures(np.array([-2.0, 0.0, 2.0]), "none", None, "times", "given")
    clip = Clip(frames, "test", ["a", "b", "c"])
    m = analyse.measure(clip, ex, _flow(clip.frames, "dis_fast"))

    def robust(task, *sets):
        return decide.decide(load_config("fast", list(sets)), clip, ex, task, m)[0].loss.robust

    assert robust("fuse-stack") == decide.ROBUST_STACK > 0
    assert robust("fuse-stack", "model.blur=on") == 0.0
    assert robust("hdr-video") == 0.0 and robust("deblur-video") == 0.0
    assert robust("fuse-stack", "loss.robust=0") == 0.0 and robust("hdr-video", "loss.robust=0.1") == 0.1


def test_a_pair_with_few_comparable_tiles_says_nothing_about_blur(monkeypatch):
    """One pair with 6 comparable tiles, 5 of them blurrier, among pairs of 37 tiles that agree: no
    blur measured (it chose a blur generator for a sharp composite); alone, the same pair counts."""
    from layercam.vision import sharpness

    tiles = {0: np.zeros(37), 1: np.array([0.0, 1.5, 1.6, 1.7, 1.8, 1.9]), 2: np.zeros(37)}
    monkeypatch.setattr(sharpness, "pair_relative_blur", lambda a, b, h, m: tiles[int(a[0, 0, 0])])
    frames = np.arange(4, dtype=np.float32)[:, None, None, None] * np.ones((4, 8, 8, 3), np.float32)
    b = analyse._blur(frames, None, None)
    assert b["blur_tile_share"] == [0.0, None, 0.0] and b["max_blur_tile_share"] < decide.BLUR_TILE_SHARE
    b = analyse._blur(frames[1:3], None, None)
    assert b["max_blur_tile_share"] > 0.8


def test_blur_in_few_pairs_of_many_is_not_a_blur_generator(monkeypatch):
    """One pair of four at 6 of 13 tiles blurrier (a sharp composite under balanced's flow chose a
    3x3 blur generator from it), the others sharp: no blur generator; the same in two pairs: one;
    a clip of two frames (one pair) still gets one from its only pair. The rule is a share of the
    pairs, not a count: two pairs of 26 (a sharp 96-frame composite) are not a blur generator,
    nine of 26 are (camera shake differs in 43-100% of its pairs)."""
    from layercam.vision import sharpness

    lone = np.array([0.0] * 7 + [1.5] * 6)
    tiles = {0: np.zeros(13), 1: lone, 2: np.zeros(13), 3: np.zeros(13)}
    monkeypatch.setattr(sharpness, "pair_relative_blur", lambda a, b, h, m: tiles[int(a[0, 0, 0])])
    frames = np.arange(5, dtype=np.float32)[:, None, None, None] * np.ones((5, 8, 8, 3), np.float32)
    clip = Clip(frames, "test", [f"{i:05d}" for i in range(5)])

    def decided(fr):
        m = {**analyse.measure(Clip(fr, "t", [str(i) for i in range(len(fr))]), _single(len(fr)),
                               None), **analyse._blur(fr, None, None)}
        return decide.decide(load_config("fast"), clip, _single(len(fr)), "deblur-video", m)

    cfg, reasons = decided(frames)
    assert cfg.model.blur == "off" and "only 1 of 4 pairs" in reasons["blur"], reasons["blur"]
    tiles[3] = lone
    assert decided(frames)[0].model.blur == "on"
    assert decided(frames[1:3])[0].model.blur == "on"
    long = np.arange(27, dtype=np.float32)[:, None, None, None] * np.ones((27, 8, 8, 3), np.float32)
    tiles.update({t: np.zeros(13) for t in range(26)})
    tiles[22] = tiles[25] = lone
    assert decided(long)[0].model.blur == "off"
    tiles.update({t: lone for t in (1, 4, 9, 13, 17, 21, 24)})
    assert decided(long)[0].model.blur == "on"


def test_one_pair_of_motion_is_not_a_layer():
    """Independent motion seen in a single pair (a flow failure between a defocused pair) is not
    enough for a second layer."""
    bg = _texture(64, 64, 0)
    fg = _texture(16, 16, 1)[..., ::-1] * 0.5 + 0.5
    frames = [bg.copy(), bg.copy(), bg.copy()]
    frames[2][10:26, 40:56] = fg  # something appears between frames 1 and 2 only
    frames[1][10:26, 30:46] = fg
    spec, m = _decide(np.stack(frames))
    assert m["moving_pairs"] <= 1 and spec.layers == 1, m


def test_no_foreground_found_means_one_layer_and_says_why():
    """The analysis chose two layers from the flow; the foreground finder found no consistent
    object: deciding again with its verdict gives one layer, with the finder's reason. A layer
    count the user set, or masks the user gave, are kept."""
    from layercam.engine.decide import unfound_foreground
    from layercam.core.presets import load_config

    cfg = load_config("fast")
    fg = {"masks": "motion segmentation",
          "verdict": {"found": False, "reason": "the candidate masks jump between frames"}}
    why = unfound_foreground(cfg, fg)
    assert why == "the candidate masks jump between frames"
    assert unfound_foreground(load_config("fast", ["model.layers=2"]), fg) is None
    assert unfound_foreground(cfg, {"masks": "given"}) is None and unfound_foreground(cfg, None) is None
    assert unfound_foreground(cfg, {"masks": "motion segmentation", "verdict": {"found": True}}) is None
    clip = SimpleNamespace(T=8, H=32, W=32)
    measures = {"independent_pairs": 1.0, "moving_pairs": 7, "independent_motion_frac": 0.1}
    exposures = SimpleNamespace(count_distinct=1, learn="none", reason="given")
    two, r2 = decide.decide(cfg, clip, exposures, "hdr-video", measures)
    assert two.model.layers == 2
    one, r1 = decide.decide(cfg, clip, exposures, "hdr-video",
                            {**measures, "foreground_found": False, "foreground_reason": why})
    assert one.model.layers == 1 and why in r1["layers"] and "no consistent" in r1["layers"]
