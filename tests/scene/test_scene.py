"""Tests of layercam.scene (encodings, fields, the layered scene): outputs finite for any input,
float32 geometry, the projective divide and log-irradiance guards."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import assume, given, strategies as st
from hypothesis.extra import numpy as hnp

from layercam.core.config import SceneConfig
from layercam.scene.encodings import DenseGrid2D, DenseGrid3D, PositionalEncoding
from layercam.scene.fields import AtlasField, LOG2_R_BOUND, apply_homography
from layercam.scene.layered import LayeredScene

from props import AUTOCAST, DTYPES, SCENE, SIZES_SMALL, _autocast, _finite, _grads_finite, _scale_params, props


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
@given(h=hnp.arrays(np.float32, (5, 3, 3),
                    elements=st.one_of(st.just(0.0), st.floats(-1e3, 1e3, width=32))),
       xy=hnp.arrays(np.float32, (5, 2), elements=st.floats(-1, 1, width=32)))
def test_projective_divide_is_guarded(h, xy):
    h[0, 2] = 0.0  # a homography sending points to infinity
    uv = apply_homography(torch.from_numpy(h), torch.from_numpy(xy))
    assert _finite(uv)


@props(25)
@given(init_log2=st.sampled_from([-1e6, -60.0, -40.0, 0.0, 40.0, 60.0, 1e6]),
       encoding=st.sampled_from(["grid", "pe"]), dtype=DTYPES,
       uv=hnp.arrays(np.float32, (8, 2), elements=st.floats(-1e4, 1e4, width=32)))
def test_atlas_log_irradiance_within_guard(init_log2, encoding, dtype, uv):
    cfg = SceneConfig(**{**SCENE.__dict__, "encoding": encoding})
    atlas = AtlasField(cfg, 8, init_log2)
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
def test_layered_scene_finite_composite_between_layers(layers, frames, scale, init_log2, h_noise,
                                                       dtype, autocast, deformation):
    assume(autocast != torch.float16 or scale <= 10)  # fp16 overflows past 65504: train.autocast offers bf16 only
    torch.manual_seed(0)
    h0 = torch.eye(3).expand(layers, frames, 3, 3) + h_noise * torch.randn(layers, frames, 3, 3)
    scene = LayeredScene(SceneConfig(**{**SCENE.__dict__, "deformation": deformation}), h0, SIZES_SMALL, init_log2)
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


def test_dense_grid_3d_levels_and_frame_slices():
    g = DenseGrid3D(levels=3, max_res=32, frames=8, features=2)
    assert g.shapes == [(2, 8), (4, 16), (8, 32)] and g.out_dim == 6
    with torch.no_grad():
        g.grids[2].zero_()
        g.grids[2][0, :, 5] = 1.0  # frame 5's slice of the finest level
    t = torch.arange(8).float()
    xyt = torch.stack([torch.zeros(8), torch.zeros(8), (2 * t + 1) / 8 - 1], 1)
    fine = g(xyt)[:, 4:]
    assert torch.allclose(fine[:, 0], (t == 5).float())  # each frame reads its own slice only
    with pytest.raises(ValueError):
        g(torch.zeros(4, 2))


def _fit_alpha(encoding: str, steps: int = 150) -> float:
    """IoU of an alpha field fitted (BCE, every pixel) to a thin moving cross (2 px wide) on 64x64 x 3 frames."""
    from layercam.scene.coords import pixel_grid
    from layercam.scene.fields import AlphaField

    torch.manual_seed(0)
    n = 64
    cfg = SceneConfig(alpha_encoding=encoding)
    field = AlphaField(cfg, 3, res=n)
    xy = pixel_grid(n, n, "cpu")
    mask = torch.zeros(3, n, n)
    for t in range(3):
        mask[t, 11 + 7 * t : 13 + 7 * t, 5:55] = 1.0
        mask[t, 5:55, 27 + 5 * t : 29 + 5 * t] = 1.0
    xs, ts = xy.repeat(3, 1), torch.arange(3).repeat_interleave(n * n)
    opt = torch.optim.Adam([{"params": [p for n, p in field.named_parameters() if "grid" not in n],
                             "lr": 5e-3},
                            {"params": [p for n, p in field.named_parameters() if "grid" in n],
                             "lr": 2e-2}])
    for _ in range(steps):
        opt.zero_grad()
        loss = torch.nn.functional.binary_cross_entropy(field(xs, ts)[:, 0], mask.reshape(-1))
        loss.backward()
        opt.step()
    with torch.no_grad():
        a = field(xs, ts)[:, 0] > 0.5
    m = mask.reshape(-1) > 0.5
    return float((a & m).sum() / (a | m).sum())


def test_alpha_grid_draws_thin_structures_the_encoding_alone_blurs():
    """In 80 steps the grid draws the 2 px cross, the positional encoding alone not yet (with the
    fixed alpha MLP, 64 x 3, it gets there by 150 steps on this toy; on real clips it stays blurred)."""
    grid, pe = _fit_alpha("grid", 80), _fit_alpha("pe", 80)
    assert grid > 0.95 and grid > pe + 0.1, (grid, pe)


def test_still_background_has_no_per_frame_motion_and_the_foreground_keeps_its_own():
    """A static camera with two layers (``Resolved.still_background``): the background maps every
    frame through its bootstrap homography alone (no gradient for its correction, no residual
    warp); the foreground's deformation stays free."""
    sizes = {"grid_max_res": 32, "alpha_grid_res": 16}
    h0 = torch.eye(3).expand(2, 4, 3, 3).clone()
    scene = LayeredScene(SceneConfig(), h0, sizes, still_background=True)
    bg, fg = scene.deformations
    assert not bg.dh.requires_grad and bg.residual is None and fg.dh.requires_grad and fg.residual is not None
    xy, t = torch.rand(16, 2) * 2 - 1, torch.randint(0, 4, (16,))
    out = scene(xy, t)
    out["log2_r"].sum().backward()
    assert torch.allclose(out["uv"][0], xy, atol=1e-6) and bg.dh.grad is None and fg.dh.grad is not None
    moving = LayeredScene(SceneConfig(), h0, sizes)  # a moving camera: free
    assert moving.deformations[0].dh.requires_grad and moving.deformations[0].residual is not None


def test_foreground_atlas_held_rows_are_a_second_lookup_in_the_same_call():
    """``held``: the foreground atlas read again at the first rows' coordinates, detached, in the
    same call; values and every gradient (the sparse grid levels' included) as a second call's."""
    torch.manual_seed(0)
    h0 = torch.eye(3).expand(2, 3, 3, 3).clone()
    scene = LayeredScene(SceneConfig(), h0, {"grid_max_res": 128, "alpha_grid_res": 16}, batch=64)
    assert any(lv.sparse for lv in scene.atlases[1].enc.levels)
    xy, t = torch.rand(64, 2) * 2 - 1, torch.randint(0, 3, (64,))

    def grads(held: bool):
        scene.zero_grad(set_to_none=True)
        out = scene(xy, t, held=16) if held else scene(xy, t)
        fg = out["fg_held"] if held else scene.atlases[1](out["uv"][1][:16].detach())
        (out["log2_r"].sum() + (fg**2).sum()).backward()
        return fg.detach(), {k: (p.grad.to_dense() if p.grad.is_sparse else p.grad).clone()
                             for k, p in scene.named_parameters() if p.grad is not None}

    (fg_a, g_a), (fg_b, g_b) = grads(True), grads(False)
    assert torch.allclose(fg_a, fg_b, atol=1e-6) and g_b.keys() <= g_a.keys()
    for k in g_a:
        assert torch.allclose(g_a[k], g_b.get(k, torch.zeros_like(g_a[k])), rtol=1e-4, atol=1e-7), k


@pytest.mark.parametrize("frames,cap", [(12, 0), (5, 0), (40, 32 * 32 * 10)])
def test_dense_grid_3d_at_frames_is_its_trilinear_lookup(frames, cap):
    """The alpha field's lookup at integer frames (each level's slices as one tall 2D image, two
    slices blended where a frame falls between them) gives the trilinear lookup's values and
    gradients, borders included."""
    torch.manual_seed(0)
    g = DenseGrid3D(levels=3, max_res=32, frames=frames, features=2, init_std=1.0, max_cells=cap)
    xy = (torch.rand(4000, 2) * 2.4 - 1.2).requires_grad_()
    t = torch.randint(0, frames, (4000,))
    tc = (2.0 * t.float() + 1.0) / frames - 1.0
    want = g(torch.cat([xy, tc[:, None]], 1))
    got = g.at_frames(xy, t, frames)
    assert torch.allclose(got, want, atol=1e-4)
    gw = torch.autograd.grad((want * torch.arange(6.0)).sum(), [xy, *g.grids])
    gg = torch.autograd.grad((got * torch.arange(6.0)).sum(), [xy, *g.grids])
    for a, b in zip(gw[1:], gg[1:]):
        assert torch.allclose(a, b, atol=1e-3, rtol=1e-3)
    # the coordinates' gradient: the same except where a lookup sits on a cell edge (either side's slope)
    close = torch.isclose(gw[0], gg[0], atol=1e-2, rtol=1e-3).all(1)
    assert close.float().mean() > 0.995

