"""Property-based checks (hypothesis) of numerical stability at the extremes.

Camera and scene modules get exposure ratios from 2^-12 to 2^12, log irradiances up to the
guard (+-40 stops) and beyond, half-precision inputs and autocast, blur-weight logits of +-1e4,
offsets at their bounds, and parameters scaled far from their initialisation; every output and
gradient must stay finite, tone curves with the monotone option (and the fixed sRGB curve) must be
monotone over [-20, 20] stops. The end-to-end cases run the whole hdr-video pipeline on tiny clips
(1x1, 2x3, odd sizes, one frame, black / white / constant frames, 16-bit grey PNGs) and check the
exported EXRs (finite, non-negative) and curves.

Examples are derandomised so that the suite is reproducible; ``LAYERCAM_EXPLORE=1`` searches ten
times as many fresh random examples.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from layercam import losses
from layercam.camera.blur import LOGIT_BOUND, BlurGenerator, apply_patch_blur
from layercam.camera.exposure import EV_BOUND, ExposureField
from layercam.camera.tone import FixedTone, ToneMapper, srgb_tone
from layercam.config import SceneConfig
from layercam.scene.encodings import DenseGrid2D, PositionalEncoding
from layercam.scene.fields import LOG2_R_BOUND, AtlasField, apply_homography
from layercam.scene.layered import LayeredScene

from conftest import TINY

_EXPLORE = bool(os.environ.get("LAYERCAM_EXPLORE"))


def props(n: int):
    """Settings for a property: ``n`` examples (x10 when exploring), no deadline, no database."""
    return settings(
        max_examples=n * (10 if _EXPLORE else 1), deadline=None, derandomize=not _EXPLORE, database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    )


DTYPES = st.sampled_from([torch.float32, torch.float16, torch.bfloat16])
AUTOCAST = st.sampled_from([None, torch.bfloat16, torch.float16])
EV = st.floats(-12.0, 12.0)  # log2 exposure: ratios 2^-12 .. 2^12
SIZES = st.sampled_from([(1, 1), (2, 3), (3, 2), (5, 7), (7, 5)])
SCENE = SceneConfig(grid_levels=2, grid_min_res=4, grid_max_res=8, atlas_width=8, deform_width=8, alpha_width=8, alpha_depth=2)
Z = torch.linspace(-20.0, 20.0, 2001)  # stops, for monotonicity


def _autocast(dtype):
    return torch.autocast("cpu", dtype=dtype) if dtype is not None else torch.autocast("cpu", enabled=False)


def _finite(*ts) -> bool:
    return all(bool(torch.isfinite(t).all()) for t in ts)


def _grads_finite(module: torch.nn.Module) -> bool:
    return all(p.grad is None or bool(torch.isfinite(p.grad).all()) for p in module.parameters())


def _scale_params(module: torch.nn.Module, scale: float) -> None:
    with torch.no_grad():
        for p in module.parameters():
            p.mul_(scale)


def _z_values(n=64, big=1e4):
    """log2 exposures z: the whole guarded range and beyond, with exact extremes."""
    edge = st.sampled_from([0.0, -big, big, -40.0, 40.0, -20.0, 20.0, 65504.0, -65504.0])
    return hnp.arrays(np.float32, (n, 3), elements=st.one_of(edge, st.floats(-big, big, width=32)))


# ------------------------------------------------------------------------------------------
# camera: tone mapper
# ------------------------------------------------------------------------------------------


@props(30)
@given(z=_z_values(), dtype=DTYPES, kind=st.sampled_from(["mlp", "lut", "monotone", "fixed"]), scale=st.sampled_from([1.0, 30.0]), autocast=AUTOCAST)
def test_tone_output_finite_in_unit_interval_with_finite_gradients(z, dtype, kind, scale, autocast):
    torch.manual_seed(0)
    tone = FixedTone() if kind == "fixed" else ToneMapper(8, 2, monotone=kind == "monotone", lut=64 if kind == "lut" else 0)
    _scale_params(tone, scale)
    zt = torch.from_numpy(z).to(dtype).float().requires_grad_(True)
    with _autocast(autocast):
        c = tone(zt.to(dtype))
    assert c.dtype == torch.float32 and _finite(c)
    assert float(c.detach().min()) >= 0.0 and float(c.detach().max()) <= 1.0
    c.sum().backward()
    assert _finite(zt.grad) and _grads_finite(tone)


incs = hnp.arrays(np.float32, (3, 96), elements=st.one_of(st.sampled_from([-1e4, 1e4, 0.0, -20.0, 30.0]), st.floats(-1e4, 1e4, width=32)))


@props(30)
@given(inc=incs, offset=hnp.arrays(np.float32, (3,), elements=st.floats(-1e4, 1e4, width=32)))
def test_monotone_tone_is_monotone_over_pm20_stops_for_any_parameters(inc, offset):
    tone = ToneMapper(8, 2, monotone=True)
    with torch.no_grad():
        tone.inc.copy_(torch.from_numpy(inc))
        tone.offset.copy_(torch.from_numpy(offset))
    logits = tone.logits(Z[:, None].expand(-1, 3).contiguous())
    curve = tone.curve(Z)
    assert _finite(logits, curve)
    assert bool((logits.diff(dim=0) >= 0).all()), "monotone logits decrease somewhere"
    assert bool((curve.diff(dim=0) >= 0).all()), "monotone curve decreases somewhere"


def test_fixed_srgb_curve_monotone_and_gradient_finite_at_extremes():
    z = torch.cat([Z, torch.tensor([-1e4, -40.0, 1.0, 1e4])]).requires_grad_(True)
    c = srgb_tone(z[:, None].expand(-1, 3))
    c.sum().backward()
    assert _finite(c, z.grad)
    assert bool((FixedTone().curve(Z).diff(dim=0) >= 0).all())


# ------------------------------------------------------------------------------------------
# camera: exposures
# ------------------------------------------------------------------------------------------


@props(40)
@given(
    log2=hnp.arrays(np.float32, st.integers(1, 6), elements=EV),
    learn=st.sampled_from(["none", "ratio", "all"]),
    delta=st.floats(-1e6, 1e6, width=32),
)
def test_exposures_bounded_finite_and_reference_fixed(log2, learn, delta):
    phase = np.arange(len(log2)) % 2
    ef = ExposureField(log2, learn, phase)
    if ef.delta is not None:
        with torch.no_grad():
            ef.delta.fill_(delta)
    v = ef.values()
    init = torch.from_numpy(log2)
    assert _finite(v)
    assert float((v - init).abs().max()) <= EV_BOUND + 1e-3
    assert float(v[0]) == pytest.approx(float(log2[0]), abs=1e-5)  # the reference frame / phase
    t = torch.arange(len(log2))
    assert ef(t).shape == (len(log2), 1)


# ------------------------------------------------------------------------------------------
# camera: blur generator
# ------------------------------------------------------------------------------------------


class _Flat(torch.nn.Module):
    """A scene of constant log irradiance ``level`` (+ a gentle ramp), any precision in."""

    def __init__(self, level: float):
        super().__init__()
        self.level = torch.nn.Parameter(torch.tensor(float(level)))

    def forward(self, xy, t):
        r = (self.level + xy.float().sum(1, keepdim=True)).expand(-1, 3)
        return {"log2_r": r.clamp(-LOG2_R_BOUND, LOG2_R_BOUND)}


@props(30)
@given(
    n=st.sampled_from([1, 3, 5]),
    max_offset=st.sampled_from([0.0, 0.5, 5.0]),
    hw=SIZES,
    logits=st.lists(st.sampled_from([-LOGIT_BOUND, 0.0, LOGIT_BOUND, 3e4, -3e4]), min_size=25, max_size=25),
    off_sign=st.sampled_from([-1e4, 0.0, 1e4]),
    level=st.sampled_from([-40.0, -20.0, 0.0, 20.0, 40.0]),
    dtype=DTYPES,
    autocast=AUTOCAST,
)
def test_blur_kernels_normalised_offsets_bounded_outputs_finite(n, max_offset, hw, logits, off_sign, level, dtype, autocast):
    torch.manual_seed(0)
    blur = BlurGenerator(n, max_offset, 2, hw, width=8, depth=2)
    k = n * n
    with torch.no_grad():  # logits of +-1e4 (and beyond the clamp), offsets driven to their bounds
        blur.weight_net.last.bias.copy_(torch.tensor(logits[:k]))
        if blur.offset_net is not None:
            blur.offset_net.last.bias.fill_(off_sign)
    xy = (torch.rand(6, 2) * 2 - 1).to(dtype)
    t = torch.tensor([0, 1, 0, 1, 1, 0])
    with _autocast(autocast):
        disp, w = blur.kernels(xy, t)
        scene = _Flat(level)
        out = blur(scene, xy, t)
    assert _finite(disp, w, out)
    assert float(w.min()) >= 0.0 and torch.allclose(w.sum(1), torch.ones(6), atol=1e-5)
    assert float((disp - blur.base).abs().max()) <= max_offset + 1e-4
    assert float(out.abs().max()) <= LOG2_R_BOUND + 1e-3
    out.sum().backward()
    assert _grads_finite(blur) and _finite(scene.level.grad)


@props(40)
@given(
    patch=hnp.arrays(np.float32, (4, 5, 3), elements=st.one_of(st.sampled_from([-40.0, 40.0, 0.0]), st.floats(-40, 40, width=32))),
    weights=hnp.arrays(np.float32, (4, 5), elements=st.one_of(st.sampled_from([0.0, 1e-45, 1.0]), st.floats(0, 1, width=32))),
    dtype=DTYPES,
)
def test_apply_patch_blur_is_a_finite_convex_blend(patch, weights, dtype):
    weights[:, 0] += 1e-3  # at least one positive weight per row
    lr = torch.from_numpy(patch).to(dtype).float().requires_grad_(True)
    w = torch.from_numpy(weights / weights.sum(1, keepdims=True)).requires_grad_(True)
    out = apply_patch_blur(lr.to(dtype), w.to(dtype))
    assert _finite(out)
    o = out.float()
    assert bool((o >= lr.min(1).values - 0.1).all()) and bool((o <= lr.max(1).values + 0.1).all())
    o.sum().backward()
    assert _finite(lr.grad, w.grad)


# ------------------------------------------------------------------------------------------
# scene
# ------------------------------------------------------------------------------------------


@props(40)
@given(h=hnp.arrays(np.float32, (5, 3, 3), elements=st.one_of(st.just(0.0), st.floats(-1e3, 1e3, width=32))), xy=hnp.arrays(np.float32, (5, 2), elements=st.floats(-1, 1, width=32)))
def test_projective_divide_is_guarded(h, xy):
    h[0, 2] = 0.0  # a homography sending points to infinity
    uv = apply_homography(torch.from_numpy(h), torch.from_numpy(xy))
    assert _finite(uv)


@props(25)
@given(init_log2=st.sampled_from([-1e6, -60.0, -40.0, 0.0, 40.0, 60.0, 1e6]), encoding=st.sampled_from(["grid", "pe"]), dtype=DTYPES,
       uv=hnp.arrays(np.float32, (8, 2), elements=st.floats(-1e4, 1e4, width=32)))
def test_atlas_log_irradiance_within_guard(init_log2, encoding, dtype, uv):
    cfg = SceneConfig(**{**SCENE.__dict__, "encoding": encoding, "pe_freqs": 3})
    atlas = AtlasField(cfg, init_log2)
    out = atlas(torch.from_numpy(uv).to(dtype))
    assert _finite(out) and float(out.abs().max()) <= LOG2_R_BOUND
    assert _finite(torch.exp2(out))
    out.sum().backward()
    assert _grads_finite(atlas)


@props(25)
@given(uv=hnp.arrays(np.float32, (8, 2), elements=st.floats(-1e4, 1e4, width=32)), dtype=DTYPES)
def test_encodings_finite_for_any_coordinates(uv, dtype):
    x = torch.from_numpy(uv).to(dtype)
    assert _finite(DenseGrid2D(2, 4, 8, 2)(x))
    assert _finite(PositionalEncoding(2, 4)(x.float()))


@props(30)
@given(
    layers=st.sampled_from([1, 2]),
    frames=st.integers(1, 3),
    scale=st.sampled_from([1.0, 10.0, 1e3]),
    init_log2=st.sampled_from([-40.0, 0.0, 12.0, 40.0]),
    h_noise=st.floats(0.0, 10.0),
    dtype=DTYPES,
    autocast=AUTOCAST,
    deformation=st.sampled_from(["homography", "mlp"]),
)
def test_layered_scene_finite_composite_between_layers(layers, frames, scale, init_log2, h_noise, dtype, autocast, deformation):
    assume(autocast != torch.float16 or scale <= 10)  # fp16 overflows past 65504: train.autocast offers bf16 only
    torch.manual_seed(0)
    h0 = torch.eye(3).expand(layers, frames, 3, 3) + h_noise * torch.randn(layers, frames, 3, 3)
    scene = LayeredScene(SceneConfig(**{**SCENE.__dict__, "deformation": deformation}), h0, init_log2)
    _scale_params(scene, scale)  # drives alpha logits, residuals and atlases to their clamps
    xy = (torch.rand(16, 2) * 2 - 1).to(dtype)
    t = torch.randint(0, frames, (16,))
    with _autocast(autocast):
        out = scene(xy, t)
    lr = out["log2_r"]
    assert lr.dtype == torch.float32 and _finite(lr, *out["uv"])
    assert float(lr.abs().max()) <= LOG2_R_BOUND
    if layers == 2:
        a = out["alpha"]
        assert _finite(a) and float(a.min()) >= 0 and float(a.max()) <= 1
        lo = torch.minimum(*out["layer_log2_r"]) - 1e-3
        hi = torch.maximum(*out["layer_log2_r"]) + 1e-3
        assert bool(((lr >= lo) & (lr <= hi)).all()), "composite outside the layers' irradiances"
    lr.sum().backward()
    assert _grads_finite(scene)


# ------------------------------------------------------------------------------------------
# losses and the model's terms
# ------------------------------------------------------------------------------------------


@props(40)
@given(
    pred=hnp.arrays(np.float32, (16, 3), elements=st.floats(0, 1, width=32)),
    target=hnp.arrays(np.float32, (16, 3), elements=st.one_of(st.sampled_from([0.0, 1.0, 1 / 255, 254 / 255]), st.floats(0, 1, width=32))),
    dtype=DTYPES,
)
def test_color_loss_one_sided_is_finite_and_never_above_plain(pred, target, dtype):
    p, tg = torch.from_numpy(pred).to(dtype), torch.from_numpy(target).to(dtype)
    plain = losses.color_loss(p, tg, "plain")
    one = losses.color_loss(p, tg, "one_sided")
    assert _finite(plain, one) and float(one) >= 0
    assert float(one) <= float(plain) + 1e-7
    # a prediction beyond the threshold on the clipped side costs nothing
    sat = torch.ones(4, 3)
    assert float(losses.color_loss(torch.full((4, 3), 0.999), sat, "one_sided")) == 0.0
    assert float(losses.color_loss(torch.full((4, 3), 1e-4), sat * 0, "one_sided")) == 0.0


def test_rigidity_and_gradient_losses_finite_on_degenerate_inputs():
    xy = torch.zeros(8, 2, requires_grad=True)
    t = torch.zeros(8, dtype=torch.long)
    r = losses.rigidity_loss(lambda p, tt: p * 0.0, xy, t, 1e-3)  # a mapping that collapses everything
    g = losses.gradient_loss(ToneMapper(8, 2), torch.tensor([[-1e4] * 3, [1e4] * 3]))
    assert _finite(r, g)


@props(8)
@given(
    ev=EV, layers=st.sampled_from([1, 2]), monotone=st.booleans(), clipped=st.sampled_from(["plain", "one_sided"]),
    blur=st.sampled_from(["off", "3x3"]), target=st.sampled_from(["black", "white", "random"]), autocast=st.sampled_from(["none", "bf16"]),
)
def test_model_loss_terms_and_gradients_finite(ev, layers, monotone, clipped, blur, target, autocast):
    from layercam.config import load_config
    from layercam.model import ImplicitCameraModel

    from conftest import decided

    torch.manual_seed(0)
    h0 = torch.eye(3).expand(layers, 2, 3, 3).clone()
    cfg = decided(load_config("fast", TINY + [f"tone.monotone={monotone}", f"loss.clipped={clipped}", "blur.width=8", "blur.depth=1"]), h0, (3, 5), layers=layers, blur=blur)
    model = ImplicitCameraModel(cfg, h0, np.array([0.0, ev], np.float32), init_log2=-ev, frame_hw=(3, 5))
    n = 32
    rgb = {"black": torch.zeros(n, 3), "white": torch.ones(n, 3), "random": torch.rand(n, 3)}[target]
    batch = {"xy": torch.rand(n, 2) * 2 - 1, "t": torch.arange(n) % 2, "rgb": rgb,
             "xy_match": torch.rand(n, 2) * 2 - 1, "t_match": (torch.arange(n) + 1) % 2, "match_ok": torch.ones(n, dtype=torch.bool)}
    with _autocast(torch.bfloat16 if autocast == "bf16" else None):
        terms = model.loss_dict(batch)
    loss = sum(terms.values())
    assert _finite(*terms.values())
    loss.backward()
    assert _grads_finite(model)


# ------------------------------------------------------------------------------------------
# io and display
# ------------------------------------------------------------------------------------------


@props(20)
@given(img=hnp.arrays(np.float32, st.tuples(st.integers(1, 5), st.integers(1, 5), st.just(3)), elements=st.floats(0, 65504, width=32)), half=st.booleans())
def test_exr_roundtrip_finite_non_negative(img, half):
    from layercam.io import read_exr, write_exr

    with tempfile.TemporaryDirectory() as d:
        write_exr(Path(d) / "a.exr", img, half=half)
        back = read_exr(Path(d) / "a.exr")
    assert back.shape == img.shape and np.isfinite(back).all() and (back >= 0).all()


def test_exr_refuses_non_finite_and_half_overflow(tmp_path):
    from layercam.io import write_exr

    for bad in (np.nan, np.inf):
        with pytest.raises(ValueError, match="non-finite"):
            write_exr(tmp_path / "x.exr", np.full((2, 2, 3), bad, np.float32))
    with pytest.raises(ValueError, match="float16"):
        write_exr(tmp_path / "y.exr", np.full((2, 2, 3), 1e5, np.float32), half=True)
    assert not (tmp_path / "x.exr").exists() and not (tmp_path / "y.exr").exists()


@props(30)
@given(
    frames=st.sampled_from(["black", "white", "constant", "random"]),
    value=st.floats(0, 1),
    log2=hnp.arrays(np.float32, st.integers(1, 4), elements=EV),
    tone=st.sampled_from(["learned", "fixed"]),
)
def test_initial_log2_finite_for_black_white_constant_frames(frames, value, log2, tone):
    from layercam.pipelines.stages import initial_log2

    shape = (len(log2), 2, 3, 3)
    f = {"black": np.zeros(shape), "white": np.ones(shape), "constant": np.full(shape, value), "random": np.random.default_rng(0).random(shape)}[frames]
    v = initial_log2(f.astype(np.float32), log2, 0.6, tone)
    assert np.isfinite(v) and abs(v) < LOG2_R_BOUND


@props(30)
@given(hdr=hnp.arrays(np.float32, (2, 3, 3, 3), elements=st.one_of(st.sampled_from([0.0, 1e-30, 2.0**-40, 2.0**40, 1e30]), st.floats(0, float(np.float32(1e30)), width=32))))
def test_display_tonemap_finite_in_unit_interval_brightest_not_darkest(hdr):
    from layercam.render import tonemap_display

    with np.errstate(over="ignore", invalid="ignore"):
        out, stats = tonemap_display(hdr)
    assert np.isfinite(out).all() and out.min() >= 0 and out.max() <= 1
    assert all(np.isfinite(v) for v in stats.values())
    lum = hdr.sum(-1).reshape(-1)
    shown = out.sum(-1).reshape(-1)
    assert shown[lum.argmax()] >= shown[lum.argmin()]


# ------------------------------------------------------------------------------------------
# end to end: tiny clips through the whole hdr-video pipeline
# ------------------------------------------------------------------------------------------

E2E = TINY + ["train.steps=6", "train.batch=64", "train.bootstrap_steps=2", "train.checkpoint_every=3", "export.chunk=4096"]


def _frames(content: str, t: int, hw: tuple[int, int], value: float) -> np.ndarray:
    rng = np.random.default_rng(t * 100 + hw[0])
    shape = (t, *hw, 3)
    if content == "black":
        return np.zeros(shape, np.float32)
    if content == "white":
        return np.ones(shape, np.float32)
    if content == "constant":
        return np.full(shape, value, np.float32)
    return rng.random(shape).astype(np.float32)


def _load_png16(frames: np.ndarray, d: Path, grey: bool):
    from layercam.io import load_clip, write_png

    for i, f in enumerate(frames):
        write_png(d / f"f{i:02d}.png", f.mean(-1) if grey else f, bit_depth=16)  # (H, W) grey or RGB, 16 bit
    clip = load_clip(d)
    assert clip.bit_depth == 16 and clip.frames.shape == frames.shape
    assert np.allclose(clip.frames, frames.mean(-1, keepdims=True) if grey else frames, atol=1e-4)
    return clip


# the named extremes always run; hypothesis adds random combinations on top
@example(hw=(1, 1), t=1, content="black", value=0.0, ev=0, learn=False, monotone=False, clipped="plain", autocast="none")
@example(hw=(1, 1), t=3, content="white", value=0.0, ev=-12, learn=False, monotone=True, clipped="one_sided", autocast="none")
@example(hw=(2, 3), t=2, content="constant", value=0.5, ev=12, learn=True, monotone=False, clipped="plain", autocast="bf16")
@example(hw=(5, 7), t=3, content="grey16", value=0.0, ev=12, learn=False, monotone=True, clipped="plain", autocast="none")
@example(hw=(7, 5), t=2, content="rgb16", value=0.0, ev=-12, learn=False, monotone=False, clipped="one_sided", autocast="bf16")
@example(hw=(2, 3), t=2, content="white", value=0.0, ev=12, learn=False, monotone=False, clipped="plain", autocast="none")
@props(6)
@given(
    hw=SIZES,
    t=st.integers(1, 3),
    content=st.sampled_from(["black", "white", "constant", "random", "grey16", "rgb16"]),
    value=st.floats(0, 1),
    ev=st.integers(-12, 12),
    learn=st.booleans(),
    monotone=st.booleans(),
    clipped=st.sampled_from(["plain", "one_sided"]),
    autocast=st.sampled_from(["none", "bf16"]),
)
def test_end_to_end_tiny_clips_export_finite_hdr_and_monotone_curves(hw, t, content, value, ev, learn, monotone, clipped, autocast):
    from layercam.io import Clip, Exposures, read_exr
    from layercam.config import load_config
    from layercam.pipelines.tasks import run_task

    frames = _frames("random" if content.endswith("16") else content, t, hw, value)
    log2 = np.where(np.arange(t) % 2 == 1, float(ev), 0.0)
    learn = learn and t > 1
    cfg = load_config("fast", E2E + [f"tone.monotone={monotone}", f"loss.clipped={clipped}", f"train.autocast={autocast}"])
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        if content.endswith("16"):
            (d / "in").mkdir()
            clip = _load_png16(frames, d / "in", grey=content == "grey16")
        else:
            clip = Clip(frames=frames, source=f"test:{content}", names=[f"{i}" for i in range(t)])
        ex = Exposures(log2, "ratio" if learn else "none", np.arange(t) % 2, "alt", "test")
        run_task("hdr-video", clip, ex, cfg, d / "run", progress=False)
        exrs = sorted((d / "run" / "hdr").glob("frame_*.exr"))
        assert len(exrs) == t
        for p in exrs:
            img = read_exr(p)
            assert img.shape == (*hw, 3) and np.isfinite(img).all() and (img >= 0).all()
        rep = json.loads((d / "run" / "report.json").read_text())
        assert rep["train"]["steps"] == 6 and np.isfinite(rep["train"]["log2_dt"]).all()
        from layercam.checkpoint import load_run_model

        model, _ = load_run_model(d / "run")
        curve = model.tone.curve(Z).numpy()
        assert np.isfinite(curve).all() and curve.min() >= 0 and curve.max() <= 1
        if monotone or rep["analysis"]["tone_mapper"] == "fixed":
            assert (np.diff(curve, axis=0) >= 0).all(), "CRF not monotone over [-20, 20] stops"
