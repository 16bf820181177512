"""Tests of layercam.camera.blur: kernel building, log-space blending, learning a known blur."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torch import nn

from layercam.camera.blur import BlurGenerator, apply_patch_blur, patch_offsets_base, sample_positions


H = W = 8


class Field(nn.Module):
    """A fixed sharp scene with LayeredScene's call signature: ``(xy, t) -> {"log2_r": (N, 3)}``.

    Stripes of period 4 px in x and 5 px in y (so a 3x3 box blur changes it a lot), a per-frame
    brightness step, and one learnable gain (to check that gradients reach the scene).
    """

    def __init__(self, h: int = H, w: int = W, freq_scale: float = 1.0):
        super().__init__()
        self.h, self.w, self.freq_scale = h, w, freq_scale
        self.gain = nn.Parameter(torch.ones(()))
        self.calls: list[int] = []

    def forward(self, xy: torch.Tensor, t: torch.Tensor) -> dict:
        assert xy.ndim == 2 and xy.shape[1] == 2 and t.shape == xy.shape[:1]
        self.calls.append(xy.shape[0])
        px = (xy[:, 0].float() + 1) / 2 * self.w
        py = (xy[:, 1].float() + 1) / 2 * self.h
        f = 1.5 * torch.sin(2 * math.pi * px / 4 * self.freq_scale) + torch.cos(2 * math.pi * py / 5 * self.freq_scale)
        f = self.gain * (f + 0.3 * t.float())
        return {"log2_r": torch.stack([f, 0.5 * f, -f], dim=1)}


def pixel_xy(h: int = H, w: int = W) -> torch.Tensor:
    ys, xs = torch.meshgrid(torch.arange(h).float(), torch.arange(w).float(), indexing="ij")
    return torch.stack([(xs.flatten() + 0.5) / w * 2 - 1, (ys.flatten() + 0.5) / h * 2 - 1], dim=1)


def box_blurred(scene: nn.Module, xy: torch.Tensor, t: torch.Tensor, n: int = 3) -> torch.Tensor:
    """Ground truth: the scene's irradiance averaged (linearly) over an n x n box of pixels."""
    pos = sample_positions(xy, patch_offsets_base(n).expand(xy.shape[0], -1, -1), (H, W))
    lr = scene(pos.reshape(-1, 2), t.repeat_interleave(n * n))["log2_r"].view(xy.shape[0], n * n, 3)
    r = torch.exp2(lr.double()).mean(1)
    return torch.log2(r).float()


def make(n: int = 3, s: float = 2.0, frames: int = 2, **kw) -> BlurGenerator:
    torch.manual_seed(0)
    return BlurGenerator(n, s, frames, (H, W), width=16, depth=2, **kw)


# -- building blocks -----------------------------------------------------------------------------
def test_patch_offsets_base():
    b = patch_offsets_base(3)
    assert b.shape == (9, 2)
    assert torch.equal(b[4], torch.zeros(2))
    assert torch.allclose(b.mean(0), torch.zeros(2))
    assert set(b[:, 0].tolist()) == {-1.0, 0.0, 1.0}
    assert torch.equal(b[1] - b[0], torch.tensor([1.0, 0.0]))  # x inner, 1 px spacing
    b5 = patch_offsets_base(5)
    assert b5.shape == (25, 2) and torch.equal(b5[12], torch.zeros(2)) and b5.abs().max() == 2
    with pytest.raises(ValueError):
        patch_offsets_base(0)


def test_sample_positions_pixel_units():
    xy = torch.tensor([[0.0, 0.0]])
    off = torch.tensor([[[1.0, 0.0], [0.0, 2.0]]])
    pos = sample_positions(xy, off, (4, 8))  # H=4, W=8
    assert torch.allclose(pos[0, 0], torch.tensor([2 / 8, 0.0]))
    assert torch.allclose(pos[0, 1], torch.tensor([0.0, 2 * 2 / 4]))
    with pytest.raises(ValueError):
        sample_positions(xy, off[0], (4, 8))


def test_apply_patch_blur_matches_direct_sum():
    g = torch.Generator().manual_seed(1)
    lr = torch.rand(6, 9, 3, generator=g, dtype=torch.float64) * 6 - 3
    w = torch.softmax(torch.randn(6, 9, generator=g, dtype=torch.float64), 1)
    direct = torch.log2((w[:, :, None] * torch.exp2(lr)).sum(1))
    assert torch.allclose(apply_patch_blur(lr, w), direct, atol=1e-10)
    # unnormalised weights are a plain weighted sum too
    assert torch.allclose(apply_patch_blur(lr, 2 * w), direct + 1, atol=1e-10)


def test_apply_patch_blur_extreme_values_finite():
    lr = torch.tensor([[[40.0], [-40.0], [40.0]], [[-40.0], [-40.0], [-40.0]]], requires_grad=True)
    w = torch.tensor([[0.5, 0.5, 0.0], [0.2, 0.3, 0.5]], requires_grad=True)
    out = apply_patch_blur(lr, w)
    assert torch.isfinite(out).all()
    assert torch.allclose(out.detach(), torch.tensor([[39.0], [-40.0]]), atol=1e-4)
    out.sum().backward()
    assert torch.isfinite(lr.grad).all() and torch.isfinite(w.grad).all()
    with pytest.raises(ValueError):
        apply_patch_blur(lr, w[:, :2])


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_apply_patch_blur_low_precision(dtype):
    lr = (torch.rand(4, 9, 3) * 80 - 40).to(dtype)
    w = torch.softmax(torch.randn(4, 9), 1).to(dtype)
    out = apply_patch_blur(lr, w)
    assert out.dtype == dtype and torch.isfinite(out).all()
    assert torch.allclose(out.float(), apply_patch_blur(lr.float(), w.float()), rtol=2e-2, atol=0.05)


# -- kernels ---------------------------------------------------------------------------------------
def test_weights_sum_to_one_and_finite_for_huge_logits():
    b = make()
    with torch.no_grad():
        b.weight_net.last.weight.normal_(0, 1e3)
        b.weight_net.last.bias.copy_(torch.tensor([1e4, -1e4] * 4 + [1e4]) * 10)
    xy, t = pixel_xy(), torch.zeros(H * W, dtype=torch.long)
    _, w = b.kernels(xy, t)
    assert torch.isfinite(w).all() and (w >= 0).all()
    assert torch.allclose(w.sum(1), torch.ones(H * W), atol=1e-5)
    out = b(Field(), xy, t)
    out.sum().backward()
    assert torch.isfinite(out).all()
    assert all(torch.isfinite(p.grad).all() for p in b.parameters() if p.grad is not None)


def test_offsets_bounded_by_max_offset():
    b = make(s=1.5)
    with torch.no_grad():
        b.offset_net.last.weight.normal_(0, 10)
        b.offset_net.last.bias.normal_(0, 100)
    xy = torch.rand(64, 2) * 4 - 2  # also outside the frame
    off, _ = b.kernels(xy, torch.randint(0, 2, (64,)))
    learned = off - b.base
    assert learned.abs().max() <= 1.5 + 1e-6
    assert learned.abs().max() > 1.0  # the bound is reached, not just respected trivially


def test_initial_kernel_is_near_sharp():
    b = make(s=5.0)
    xy, t = pixel_xy(), torch.randint(0, 2, (H * W,))
    off, w = b.kernels(xy, t)
    assert torch.equal(off, b.base.expand(H * W, -1, -1))  # starts as the plain n x n patch
    assert torch.allclose(w[:, 4], torch.full((H * W,), 0.9), atol=1e-5)
    smooth = Field(freq_scale=0.1)
    sharp = smooth(xy, t)["log2_r"]
    blurry = b(smooth, xy, t, sharp)
    assert (blurry - sharp).abs().max() < 0.05


def test_constant_scene_is_unchanged():
    class Const(nn.Module):
        def forward(self, xy, t):
            return {"log2_r": torch.full((xy.shape[0], 3), 7.0)}

    b = make(s=3.0)
    with torch.no_grad():
        for p in b.parameters():
            p.normal_()
    xy = pixel_xy()
    assert torch.allclose(b(Const(), xy, torch.zeros(H * W, dtype=torch.long)), torch.full((H * W, 3), 7.0), atol=1e-5)


# -- learning ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("s", [0.0, 2.0])
def test_learns_known_box_blur(s):
    scene = Field().requires_grad_(False)
    xy = pixel_xy().repeat(2, 1)
    t = torch.arange(2).repeat_interleave(H * W)
    target = box_blurred(scene, xy, t)
    b = make(s=s)
    opt = torch.optim.Adam(b.parameters(), lr=1e-2)

    def err():
        return ((b(scene, xy, t, scene(xy, t)) - target) ** 2).mean()

    with torch.no_grad():
        e0 = err().item()
    for _ in range(150):
        opt.zero_grad()
        loss = err()
        loss.backward()
        opt.step()
    with torch.no_grad():
        e1 = err().item()
    assert e0 > 0.1
    assert e1 < e0 / 20, (e0, e1)


def test_gradient_reaches_scene_parameters():
    scene = Field()
    b = make()
    xy, t = pixel_xy(), torch.zeros(H * W, dtype=torch.long)
    b(scene, xy, t, scene(xy, t)).pow(2).mean().backward()
    assert scene.gain.grad is not None and scene.gain.grad.abs() > 0
    assert b.weight_net.last.weight.grad.abs().sum() > 0


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_low_precision_inputs_no_nan(dtype):
    scene = Field()
    b = make()
    xy, t = pixel_xy().to(dtype), torch.randint(0, 2, (H * W,))
    out = b(scene, xy, t, scene(xy, t))
    out.sum().backward()
    assert torch.isfinite(out).all()
    assert all(torch.isfinite(p.grad).all() for p in b.parameters() if p.grad is not None)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = b(scene, pixel_xy(), t)
    assert out.dtype == torch.float32 and torch.isfinite(out).all()


def test_patch_5x5():
    b = make(n=5, s=5.0)
    assert b.K == 25
    xy, t = pixel_xy(), torch.zeros(H * W, dtype=torch.long)
    off, w = b.kernels(xy, t)
    assert off.shape == (H * W, 25, 2) and w.shape == (H * W, 25)
    assert torch.allclose(w[:, 12], torch.full((H * W,), 0.9), atol=1e-5)
    scene = Field()
    out = b(scene, xy, t, scene(xy, t))
    assert out.shape == (H * W, 3) and torch.isfinite(out).all()
    assert scene.calls[-1] == H * W * 25  # all samples in one call
    with pytest.raises(ValueError):
        BlurGenerator(4, 1.0, 1, (H, W))


def test_fixed_patch_s0():
    b = make(s=0.0)
    assert b.offset_net is None
    xy, t = pixel_xy(), torch.randint(0, 2, (H * W,))
    off, _ = b.kernels(xy, t)
    assert torch.equal(off, b.base.expand(H * W, -1, -1))
    scene = Field()
    reuse = b(scene, xy, t, scene(xy, t))
    assert scene.calls[-1] == H * W * 8  # centre taken from `out`
    fresh = b(scene, xy, t)
    assert scene.calls[-1] == H * W * 9
    assert torch.allclose(reuse, fresh, atol=1e-5)


def test_depth_input():
    b = make(use_depth=True)
    xy, t = pixel_xy(), torch.zeros(H * W, dtype=torch.long)
    with torch.no_grad():
        b.weight_net.last.weight.normal_()
    _, w_near = b.kernels(xy, t, depth=torch.zeros(H * W, 1))
    _, w_far = b.kernels(xy, t, depth=torch.ones(H * W, 1))
    assert not torch.allclose(w_near, w_far)
    assert b(Field(), xy, t, depth=torch.ones(H * W, 1)).shape == (H * W, 3)
    with pytest.raises(ValueError, match="use_depth"):
        b(Field(), xy, t)


def test_shape_checks():
    b = make()
    with pytest.raises(ValueError):
        b(Field(), torch.zeros(4, 3), torch.zeros(4, dtype=torch.long))
    with pytest.raises(ValueError):
        b(Field(), torch.zeros(4, 2), torch.zeros(5, dtype=torch.long))
    with pytest.raises(ValueError):
        b.kernels(torch.zeros(4, 2), torch.zeros(4))  # float t: use t_blur


def test_t_blur_interpolates_between_frames():
    """Frame 0 is sharp, frame 1 box-blurred; at t_blur = 0.5 the kernel lies between the two."""
    scene = Field().requires_grad_(False)
    xy1 = pixel_xy()
    xy = xy1.repeat(2, 1)
    t = torch.arange(2).repeat_interleave(H * W)
    target = torch.cat([scene(xy1, t[: H * W])["log2_r"], box_blurred(scene, xy1, t[H * W :])])
    b = make(s=0.0)
    opt = torch.optim.Adam(b.parameters(), lr=1e-2)
    for _ in range(150):
        opt.zero_grad()
        ((b(scene, xy, t, scene(xy, t)) - target) ** 2).mean().backward()
        opt.step()
    m = H * W
    with torch.no_grad():
        _, w0 = b.kernels(xy1, torch.zeros(m, dtype=torch.long))
        _, w1 = b.kernels(xy1, torch.ones(m, dtype=torch.long))
        _, w0f = b.kernels(xy1, t_blur=torch.zeros(m))
        _, w1f = b.kernels(xy1, t_blur=torch.ones(m))
        _, wm = b.kernels(xy1, t_blur=torch.full((m,), 0.5))
    assert torch.allclose(w0f, w0) and torch.allclose(w1f, w1)  # integer t_blur = frame lookup
    assert w0[:, 4].mean() > w1[:, 4].mean() + 0.3  # the frames learned different blur
    lo, hi = torch.minimum(w0, w1), torch.maximum(w0, w1)
    assert ((wm >= lo - 1e-2) & (wm <= hi + 1e-2)).all()
    assert torch.allclose(wm.sum(1), torch.ones(m), atol=1e-5)
    # the scene still sees the integer frame; only the blur nets see t_blur
    out = b(scene, xy1, torch.zeros(m, dtype=torch.long), t_blur=torch.full((m,), 0.5))
    assert torch.isfinite(out).all()


def test_in_model():
    from layercam.core.config import Config
    from layercam.engine.model import ImplicitCameraModel

    from conftest import decided

    torch.manual_seed(0)
    h0 = torch.eye(3).expand(1, 3, 3, 3).clone()
    model = ImplicitCameraModel(decided(Config(), h0, (H, W), blur="3x3"), h0, np.zeros(3), frame_hw=(H, W))
    xy, t = pixel_xy(), torch.randint(0, 3, (H * W,))
    out = model(xy, t)
    assert out["rgb"].shape == (H * W, 3) and torch.isfinite(out["rgb"]).all()
    terms = model.loss_dict({"xy": xy, "t": t, "rgb": torch.rand(H * W, 3)})
    sum(terms.values()).backward()
    assert model.blur.weight_net.last.weight.grad is not None


def test_zero_mean_offsets_cannot_translate_the_patch():
    """``zero_mean_offsets``: whatever the offset net outputs, a patch's mean displacement is its
    pixel, so the offsets can shape and spread the patch but not shift it; s = 0 is unchanged."""
    b = make(s=3.0, zero_mean_offsets=True)
    with torch.no_grad():
        b.offset_net.last.bias.normal_(0, 3)
        b.offset_net.last.weight.normal_(0, 1)
    xy, t = pixel_xy(), torch.randint(0, 2, (H * W,))
    off, w = b.kernels(xy, t)
    assert torch.allclose(off.mean(1), torch.zeros(H * W, 2), atol=1e-5)
    learned = off - b.base
    assert learned.abs().max() > 0.5 and learned.abs().max() <= 6.0 + 1e-5  # moves, within 2 s
    out = b(Field(), xy, t)
    out.sum().backward()
    assert torch.isfinite(out).all() and b.offset_net.last.weight.grad.abs().sum() > 0
    plain = make(s=3.0)
    with torch.no_grad():
        plain.offset_net.last.bias.fill_(2.0)
    assert plain.kernels(xy, t)[0].mean(1).abs().min() > 1.0  # without it the patch translates
    fixed = make(s=0.0, zero_mean_offsets=True)
    assert torch.equal(fixed.kernels(xy, t)[0], fixed.base.expand(H * W, -1, -1))


