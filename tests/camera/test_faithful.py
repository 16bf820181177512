"""Faithful to the frame: the export keeps the model where it explains the frame within noise and
takes the frame where it does not; clipped and floor channels bound the result."""

from __future__ import annotations

import numpy as np
import pytest

from layercam.camera import faithful

from layercam.core import visibility


def _textured(h=48, w=48, seed=0):
    import cv2

    rng = np.random.default_rng(seed)
    t = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 2.0)
    t = (t - t.min()) / (t.max() - t.min())
    return np.repeat(t[..., None], 3, -1) * 0.6 + 0.2


def test_noise_only_keeps_the_model_a_ghost_takes_the_frame():
    rng = np.random.default_rng(1)
    pred = _textured()
    frame = np.clip(pred + rng.normal(0, 0.01, pred.shape), 0, 1).astype(np.float32)
    w, info = faithful.fidelity_weight(frame, pred)
    assert float(w.mean()) < 0.05 and abs(info["noise"][0] - 0.01) < 0.003
    ghost = frame.copy()
    ghost[16:32, 16:32] = 1.0 - ghost[16:32, 16:32]  # something the model does not have
    w, _ = faithful.fidelity_weight(ghost, pred)
    assert float(w[19:29, 19:29].mean()) > 0.9
    assert float(w[:, 36:].mean()) < 0.05  # away from it the model is kept


def test_clipped_and_floor_channels_get_no_weight():
    f = np.full((4, 4, 3), 0.5, np.float32)
    f[0, :, 0] = 1.0
    f[1, :, 1] = 0.0
    f[3, :, 2] = 248 / 255  # a camera that clips at 248
    e = faithful.exposure_weight(f)
    assert (e[0, :, 0] == 0).all() and (e[1, :, 1] == 0).all() and (e[2] == 1).all() and (e[3, :, 2] > 0).all()
    levels = visibility.clip_levels(f)
    assert abs(levels[2] * 255 - 247.5) < 1e-3 and abs(levels[1] * 255 - 254.5) < 1e-3
    assert (faithful.exposure_weight(f, levels)[3, :, 2] == 0).all()


def test_export_agrees_with_the_frame_where_the_model_is_wrong(tiny_scene, tiny_exposures, tmp_path):
    """A tiny trained run; a patch of one frame replaced by content no frame has: the faithful HDR of
    that frame follows the patch (through the inverse camera), the model's does not; the frame's
    clipped and floor channels bound it."""
    from layercam.core.presets import load_config
    from layercam.pipelines.tasks import run_task
    from layercam.scene.render import inverse_tone

    from conftest import TINY

    ctx = run_task("hdr-video", tiny_scene.clip, tiny_exposures,
                   load_config("fast", TINY + ["train.steps=60"]), tmp_path / "run", progress=False)
    model, t = ctx.model, 1
    frame = tiny_scene.clip.frames[t].copy()
    # a checkerboard of 3 px squares
    frame[8:20, 8:20] = 0.5 + 0.4 * ((np.indices((12, 12)) // 3).sum(0) % 2)[..., None]
    res = faithful.faithful_log2(model, frame, t)
    target = inverse_tone(model, frame, float(model.exposure.values()[t]))
    inside = (slice(10, 18), slice(10, 18))
    err_faithful = np.abs(res["log2_r"][inside] - target[inside]).mean()
    err_model = np.abs(res["model_log2_r"][inside] - target[inside]).mean()
    assert err_faithful < 0.25 * err_model, (err_faithful, err_model)
    sigma = faithful.frame_noise(frame, faithful.exposure_weight(frame))
    lower, upper = faithful.clip_bounds(model, frame, float(model.exposure.values()[t]),
                                        np.full(3, 254.5 / 255, np.float32), sigma)
    assert (res["log2_r"] >= lower).all() and (res["log2_r"] <= upper).all()
    assert np.isfinite(res["log2_r"]).all()


def test_neighbour_fill_moves_corrections_along_the_flow():
    """A neighbour's correction arrives in this frame's view along the flow, weighted by how much
    of it the neighbour kept; where the flow is inconsistent (NaN) it lends nothing; two neighbours
    average, one that kept little is diluted towards the model (0)."""
    h, w = 12, 16
    delta = np.zeros((h, w, 3), np.float32)
    delta[:, 8:] = 1.0  # the neighbour corrected its right half by one stop
    full = np.ones((h, w, 3), np.float32)
    flow = np.zeros((h, w, 2), np.float32)
    flow[..., 0] = 2.0  # this frame's pixel x is the neighbour's x + 2
    flow[:2] = np.nan   # inconsistent in the top rows
    fill, support = faithful.neighbour_fill([(full * delta, full, flow)])
    assert np.allclose(fill[2:, 6:14], 1.0) and np.allclose(fill[2:, :5], 0.0) and np.allclose(fill[:2], 0.0)
    assert np.allclose(support[:2], 0.0) and np.allclose(support[2:, :13], 1.0)
    half, _ = faithful.neighbour_fill([(0.25 * full * delta, 0.25 * full, np.zeros((h, w, 2), np.float32))])
    assert np.allclose(half[:, 9:], 0.25)
    two, _ = faithful.neighbour_fill([(full * delta, full, np.zeros((h, w, 2), np.float32)),
                                      (full * 0.0, full, np.zeros((h, w, 2), np.float32))])
    assert np.allclose(two[:, 9:], 0.5)
    assert faithful.neighbour_fill([]) is None


class _GammaCamera(__import__("torch").nn.Module):
    """A known camera for the merge's arithmetic: ``c = clip(2^(z + dt), 0, 1)^(1/2.2)``."""

    def __init__(self):
        import torch

        super().__init__()
        self.p = torch.nn.Parameter(torch.zeros(1))

    def tone_map(self, z, dt):
        import torch

        return torch.clamp(torch.exp2(z + dt), 0, 1) ** (1 / 2.2)


def test_merge_takes_neighbours_that_agree_and_leaves_a_ghost_to_the_frame():
    """A short frame and its long neighbour (3 stops) see the same scene: the merge weighs the long
    one 8 times and its error falls towards the long frame's; where the neighbour holds something
    the frame does not (a ghost), the frame's own measurement stays."""
    rng = np.random.default_rng(0)
    cam = _GammaCamera()
    z = np.log2(_textured() * 0.1).astype(np.float32)  # the scene, log2 irradiance: short frame mid-grey
    z_t = z + rng.normal(0, 0.05, z.shape).astype(np.float32)  # the short frame's noisier measurement
    z_n = z + rng.normal(0, 0.01, z.shape).astype(np.float32)
    z_n[16:32, 16:32] += 2.0  # the neighbour saw something else here
    from layercam.scene.render import tone_map_log2

    frame = tone_map_log2(cam, z_t, 0.0)
    a_t = faithful.merge_weight(faithful.exposure_weight(frame), 0.0, [0.0, 3.0])
    a_n = faithful.merge_weight(np.ones_like(frame), 3.0, [0.0, 3.0])
    flow = np.zeros(z.shape[:2] + (2,), np.float32)
    merged, weight = faithful.merge_neighbours((z_t, a_t), [(z_n, a_n, flow)], frame, cam, 0.0,
                                               np.full(3, 254.5 / 255, np.float32),
                                               np.full(3, 0.01, np.float32))
    far = np.s_[:, 40:]
    err = lambda a: float(np.abs(a - z)[far].mean())  # noqa: E731
    assert err(merged) < 0.3 * err(z_t)
    assert float(np.abs(merged - z_t)[20:28, 20:28].mean()) < 0.05  # the ghost is not merged in
    assert abs(float(weight[far].mean()) - 1.125) < 0.01  # 1 for the long frame, 1/8 for the short one


class _GammaTone(__import__("torch").nn.Module):
    """The tone curve of :class:`_GammaCamera` as the export reads it (``model.tone.curve``)."""

    def __init__(self):
        import torch

        super().__init__()
        self.p = torch.nn.Parameter(torch.zeros(1))

    def curve(self, z):
        import torch

        return (torch.clamp(torch.exp2(z), 0, 1) ** (1 / 2.2))[:, None].expand(-1, 3)


def test_clipped_in_every_frame_keeps_to_the_shortest_exposures_clipping_point():
    """Where every frame of a static stack clipped, the model's fit to nothing (here 3 stops above
    the short frame's clipping point, with texture) is not exported with ``clipped="clip"``: the
    irradiance is held at the clipping point of the shortest exposure, flat; elsewhere, and with
    ``clipped="model"`` (the default), the model's own level stays."""
    import torch

    model = torch.nn.Module()
    model.tone = _GammaTone()
    h, w = 24, 24
    levels = np.full(3, 254.5 / 255, np.float32)
    dts = np.array([0.0, 2.0], np.float32)
    z_model = np.full((h, w, 3), -3.0, np.float32)
    z_model[:, 12:] = 3.0 + 0.5 * np.sin(np.arange(12))[None, :, None]  # invented structure where both clipped
    frames = np.stack([np.clip(np.exp2(z_model + dt), 0, 1) ** (1 / 2.2) for dt in dts]).astype(np.float32)
    assert (frames[:, :, 12:] >= levels).all() and (frames[:, :, :12] < levels).all()
    corr = {"model_log2_r": z_model, "delta": np.zeros_like(z_model),
            "weight": np.zeros_like(z_model),
            "exposed": faithful.exposure_weight(frames[0], levels),
            "log2_dts": dts, "levels": levels, "info": {"sigma": np.full(3, 0.002, np.float32)}}
    clip = faithful.faithful_log2(model, frames[0], 0, levels, frames,
                                  corr=dict(corr, info=dict(corr["info"])), clipped="clip")
    kept = faithful.faithful_log2(model, frames[0], 0, levels, frames, corr=dict(corr, info=dict(corr["info"])))
    z_clip = float(np.log2(254.0 / 255) * 2.2)  # where the gamma camera reaches the last code
                                                # inverse_tone reads at dt 0
    assert clip["unseen"][:, 12:].all() and not clip["unseen"][:, :12].any()
    assert np.allclose(clip["log2_r"][:, 12:], z_clip, atol=0.02)  # flat, at the short frame's clipping point
    assert kept["log2_r"][:, 12:].mean() > z_clip + 2.5  # the model's level
    assert np.allclose(clip["log2_r"][:, :12], -3.0, atol=1e-4) and np.allclose(kept["log2_r"][:, :12], -3.0, atol=1e-4)
    with pytest.raises(ValueError, match="clipped-everywhere"):
        faithful.faithful_log2(model, frames[0], 0, levels, frames,
                               corr=dict(corr, info=dict(corr["info"])), clipped="bright")


def test_a_compressed_frames_small_measured_noise_is_floored():
    """An mp4's measured noise misses its compression error: a frame whose measured noise is 0.3
    code and which the model misses by 1.5 codes everywhere keeps the model (weight near 0), while a
    real disagreement of 12 codes still takes the frame."""
    rng = np.random.default_rng(0)
    frame = np.clip(0.5 + rng.normal(0, 0.3 / 255, (32, 32, 3)), 0, 1).astype(np.float32)
    w, info = faithful.fidelity_weight(frame, frame + 1.5 / 255)
    assert min(info["noise"]) >= faithful.NOISE_FLOOR - 1e-5
    assert float(w.mean()) < 0.05
    w_far, _ = faithful.fidelity_weight(frame, frame + 12.0 / 255)
    assert float(w_far.mean()) > 0.9


def test_noise_log2_reads_the_frames_noise_through_the_camera():
    """The variance the frame's noise puts into its log irradiance is ``(sigma dz/dc)^2``: for a
    gamma camera ``dz/dc = 2.2 / (c ln 2)``, larger in the darks; none where the frame clipped or
    sat at the floor."""
    import torch

    model = torch.nn.Module()
    model.tone = _GammaTone()
    frame = np.full((4, 8, 3), 0.5, np.float32)
    frame[1] = 0.1
    frame[2, :, 0] = 1.0
    frame[3, :, 1] = 0.0
    sigma = np.full(3, 0.01, np.float32)
    var = faithful.noise_log2(model, frame, 0.0, sigma, faithful.exposure_weight(frame))
    want = (0.01 * 2.2 / (frame * np.log(2))) ** 2
    assert np.allclose(var[0], want[0], rtol=0.03) and np.allclose(var[1], want[1], rtol=0.03)
    assert var[1, 0, 0] > 20 * var[0, 0, 0]
    assert (var[2, :, 0] == 0).all() and (var[3, :, 1] == 0).all() and (var[2, :, 1] > 0).all()


def test_denoise_removes_the_noise_and_keeps_edges_and_texture_above_it():
    """Lee's filter with the true noise variance: on flat regions the error to the clean signal falls
    to under half; a step of 30 noise deviations and a texture of 5 keep their contrast; where the
    variance is 0 nothing changes."""
    rng = np.random.default_rng(0)
    h, w, s = 64, 64, 0.1
    clean = np.zeros((h, w, 3), np.float32)
    clean[:, 32:] = 3.0  # a step: 30 deviations
    clean[:, 48:] += 0.5 * ((np.arange(16) // 2) % 2)[None, :, None]  # a texture of 2 px stripes, 5 deviations
    z = (clean + rng.normal(0, s, clean.shape)).astype(np.float32)
    var = np.full(z.shape, s * s, np.float32)
    out = faithful.denoise_log2(z, var)
    flat = np.s_[:, 4:26]
    rms = lambda a: float(np.sqrt(((a - clean)[flat] ** 2).mean()))  # noqa: E731
    assert rms(out) < 0.5 * rms(z)
    step = float(out[:, 33:36].mean() - out[:, 28:31].mean())
    assert abs(step - 3.0) < 0.1
    stripes = out[:, 50:62].mean((0, 2))
    assert float(stripes[0::4].mean() - stripes[2::4].mean()) > 0.35  # most of the 0.5 contrast
                                                                      # kept (columns 50, 51 are
                                                                      # bright)
    var[:, :16] = 0.0
    assert np.array_equal(faithful.denoise_log2(z, var)[:, :16], z[:, :16])



def test_an_isolated_floor_pixel_bounds_nothing_a_dark_region_does():
    """A channel at the floor bounds the irradiance from above where its neighbourhood is dark too;
    a single pixel noise took to 0 amid mid-grey bounds nothing (it came out as a black speck)."""
    import torch

    model = torch.nn.Module()
    model.tone = _GammaTone()
    frame = np.full((12, 12, 3), 0.3, np.float32)
    frame[6, 6, 0] = 0.0  # noise took it to 0
    frame[:, :3] = 0.0  # a dark region
    lower, upper = faithful.clip_bounds(model, frame, 0.0, np.full(3, 254.5 / 255, np.float32),
                                        np.full(3, 0.01, np.float32))
    assert np.isinf(upper[6, 6, 0]) and np.isfinite(upper[:, :2]).all()
    assert np.isinf(upper[:, 3:]).all()
