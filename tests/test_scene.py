"""Tests of layercam.scene (encodings, fields, the layered scene): outputs finite for any input,
float32 geometry, the projective divide and log-irradiance guards."""

from __future__ import annotations

import numpy as np
import torch
from hypothesis import assume, given, strategies as st
from hypothesis.extra import numpy as hnp

from layercam.config import SceneConfig
from layercam.scene.encodings import DenseGrid2D, PositionalEncoding
from layercam.scene.fields import AtlasField, LOG2_R_BOUND, apply_homography
from layercam.scene.layered import LayeredScene

from props import AUTOCAST, DTYPES, SCENE, _autocast, _finite, _grads_finite, _scale_params, props


def test_homography_runs_in_float32_under_autocast():
    from layercam.scene.fields import apply_homography

    h = torch.eye(3).expand(64, 3, 3).clone()
    h[:, 0, 2] = 0.123456
    h[:, 2, 0] = 0.01
    xy = torch.rand(64, 2) * 2 - 1
    ref = apply_homography(h, xy)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = apply_homography(h, xy)
    assert out.dtype == torch.float32 and torch.equal(out, ref)


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
