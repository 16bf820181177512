"""Tests of layercam.camera.tone: the tone mapper's curves stay finite and in (0, 1) for any input
or parameters; the fixed curve is monotone; the starting irradiance is finite for any frames."""

from __future__ import annotations

import numpy as np
import torch
from hypothesis import given, strategies as st
from hypothesis.extra import numpy as hnp

from layercam.camera.tone import FixedTone, ToneMapper, srgb_tone
from layercam.scene.fields import LOG2_R_BOUND

from props import AUTOCAST, DTYPES, EV, Z, _autocast, _finite, _grads_finite, _scale_params, _z_values, props


@props(30)
@given(z=_z_values(), dtype=DTYPES, kind=st.sampled_from(["mlp", "lut", "fixed"]),
       scale=st.sampled_from([1.0, 30.0]), autocast=AUTOCAST)
def test_tone_output_finite_in_unit_interval_with_finite_gradients(z, dtype, kind, scale, autocast):
    torch.manual_seed(0)
    tone = FixedTone() if kind == "fixed" else ToneMapper(8, 2, lut=64 if kind == "lut" else 0)
    _scale_params(tone, scale)
    zt = torch.from_numpy(z).to(dtype).float().requires_grad_(True)
    with _autocast(autocast):
        c = tone(zt.to(dtype))
    assert c.dtype == torch.float32 and _finite(c)
    assert float(c.detach().min()) >= 0.0 and float(c.detach().max()) <= 1.0
    c.sum().backward()
    assert _finite(zt.grad) and _grads_finite(tone)


def test_fixed_srgb_curve_monotone_and_gradient_finite_at_extremes():
    z = torch.cat([Z, torch.tensor([-1e4, -40.0, 1.0, 1e4])]).requires_grad_(True)
    c = srgb_tone(z[:, None].expand(-1, 3))
    c.sum().backward()
    assert _finite(c, z.grad)
    assert bool((FixedTone().curve(Z).diff(dim=0) >= 0).all())


@props(30)
@given(
    frames=st.sampled_from(["black", "white", "constant", "random"]),
    value=st.floats(0, 1),
    log2=hnp.arrays(np.float32, st.integers(1, 4), elements=EV),
    tone=st.sampled_from(["learned", "fixed"]),
)
def test_initial_log2_finite_for_black_white_constant_frames(frames, value, log2, tone):
    from layercam.camera.tone import initial_log2

    shape = (len(log2), 2, 3, 3)
    f = {"black": np.zeros(shape), "white": np.ones(shape), "constant": np.full(shape, value),
         "random": np.random.default_rng(0).random(shape)}[frames]
    v = initial_log2(f.astype(np.float32), log2, tone, 0.6)
    assert np.isfinite(v) and abs(v) < LOG2_R_BOUND
