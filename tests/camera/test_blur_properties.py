"""Property tests of the blur generator (hypothesis): normalised kernels, bounded offsets, finite convex blends."""

from __future__ import annotations

import numpy as np
import torch
from hypothesis import given, strategies as st
from hypothesis.extra import numpy as hnp

from layercam.camera.blur import BlurGenerator, LOGIT_BOUND, apply_patch_blur
from layercam.scene.fields import LOG2_R_BOUND

from props import AUTOCAST, DTYPES, SIZES, _autocast, _finite, _grads_finite, props


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
def test_blur_kernels_normalised_offsets_bounded_outputs_finite(n, max_offset, hw, logits, off_sign,
    level, dtype, autocast):
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
    patch=hnp.arrays(np.float32, (4, 5, 3),
                     elements=st.one_of(st.sampled_from([-40.0, 40.0, 0.0]),
                                        st.floats(-40, 40, width=32))),
    weights=hnp.arrays(np.float32, (4, 5),
                       elements=st.one_of(st.sampled_from([0.0, 1e-45, 1.0]),
                                          st.floats(0, 1, width=32))),
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
