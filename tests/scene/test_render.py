"""Tests of layercam.scene.render: the one chunked renderer and the display tonemap."""

from __future__ import annotations

import numpy as np
from hypothesis import given, strategies as st
from hypothesis.extra import numpy as hnp

from props import props


@props(30)
@given(hdr=hnp.arrays(np.float32, (2, 3, 3, 3),
                      elements=st.one_of(st.sampled_from([0.0, 1e-30, 2.0**-40, 2.0**40, 1e30]),
                                         st.floats(0, float(np.float32(1e30)), width=32))))
def test_display_tonemap_finite_in_unit_interval_brightest_not_darkest(hdr):
    from layercam.scene.render import tonemap_display

    with np.errstate(over="ignore", invalid="ignore"):
        out, stats = tonemap_display(hdr)
    assert np.isfinite(out).all() and out.min() >= 0 and out.max() <= 1
    assert all(np.isfinite(v) for v in stats.values())
    lum = hdr.sum(-1).reshape(-1)
    shown = out.sum(-1).reshape(-1)
    assert shown[lum.argmax()] >= shown[lum.argmin()]


def _two_layer_blur_model():
    import torch

    from layercam.core.presets import load_config
    from layercam.engine.model import ImplicitCameraModel

    from conftest import TINY, decided

    torch.manual_seed(0)
    h0 = torch.eye(3).expand(2, 3, 3, 3).clone()
    cfg = decided(load_config("fast", TINY), h0, (6, 5), layers=2, blur="3x3", max_offset=2.0)
    return ImplicitCameraModel(cfg, h0, np.array([0.0, 1.0, 2.0], np.float32), frame_hw=(6, 5)).eval()


def test_render_frame_outputs_agree_with_each_other_and_the_model():
    import pytest
    import torch

    from layercam.scene.coords import pixel_grid
    from layercam.scene.render import composite_layers, render_frame

    model = _two_layer_blur_model()
    everything = ("hdr", "log2_r", "layers", "ldr", "uv", "alpha")
    full = render_frame(model, 1, (6, 5), everything)
    np.testing.assert_allclose(full["hdr"], np.exp2(full["log2_r"]), rtol=1e-6)
    np.testing.assert_allclose(composite_layers([np.exp2(v) for v in full["layers"]],
                                                full["alpha"]), full["hdr"], rtol=1e-4)
    assert len(full["uv"]) == 2 and full["uv"][0].shape == (6, 5, 2) and full["alpha"].shape == (6, 5)
    small = render_frame(model, 1, (6, 5), everything, chunk=7)  # chunks (and chunks / K with the blur) of any size
    for k in ("hdr", "ldr", "alpha"):
        np.testing.assert_allclose(small[k], full[k], rtol=1e-5, atol=1e-7)
    geo = render_frame(model, 1, (6, 5), ("uv", "alpha"))  # geometry only: no atlas, no camera
    np.testing.assert_array_equal(geo["alpha"], full["alpha"])
    with torch.no_grad():
        xy, t = pixel_grid(6, 5), torch.ones(30, dtype=torch.long)
        sharp = model(xy, t, blur=False)["rgb"].view(6, 5, 3).numpy()
        blurred = model(xy, t, blur=True)["rgb"].view(6, 5, 3).numpy()
    np.testing.assert_allclose(full["ldr"], sharp, rtol=1e-6)
    np.testing.assert_allclose(render_frame(model, 1, (6, 5), "ldr", blur=True)["ldr"], blurred, rtol=1e-5, atol=1e-7)
    np.testing.assert_array_equal(render_frame(model, 1, (6, 5), "ldr", log2_dt=1.0)["ldr"],
                                  full["ldr"])  # frame 1's own exposure
    assert not np.allclose(render_frame(model, 1, (6, 5), "ldr", log2_dt=3.0)["ldr"], full["ldr"])
    with pytest.raises(ValueError, match="unknown render output"):
        render_frame(model, 0, (6, 5), "depth")


def test_tone_mapping_in_chunks_is_the_tone_mapping():
    """``tone_map_log2`` evaluates a large image a chunk at a time (a per-pixel tone mapper of the
    paper's width held 6 GB for a 2048^2 atlas at once): the same values as in one go."""
    import torch

    from layercam.scene.render import tone_map_log2

    model = _two_layer_blur_model()
    z = np.random.default_rng(0).normal(0, 3, (37, 11, 3)).astype(np.float32)
    whole = tone_map_log2(model, z, 1.0)
    with torch.no_grad():
        direct = model.tone_map(torch.as_tensor(z.reshape(-1, 3)), torch.ones(37 * 11, 1)).numpy().reshape(z.shape)
    # the products' blocking
    np.testing.assert_allclose(tone_map_log2(model, z, 1.0, chunk=50), whole, rtol=0, atol=1e-6)
    np.testing.assert_allclose(whole, direct, rtol=1e-6, atol=1e-7)


def test_render_frame_centred_blur_and_stride():
    """``centred``: the learned PSFs with their weighted centres moved onto their pixels (the sharp
    export's check), as a generator built ``centre_exact`` renders them; ``stride``: every k-th
    pixel of every k-th row of the full render, exactly."""
    import torch

    from layercam.scene.render import render_frame

    model = _two_layer_blur_model()
    torch.manual_seed(1)
    with torch.no_grad():  # a scene with detail, and PSFs off their pixels: more weight on one side of the patch
        for p in model.scene.atlases.parameters():
            p.add_(torch.randn_like(p))
        model.blur.weight_net.last.bias.copy_(torch.linspace(-2.0, 2.0, model.blur.K))
    as_learned = render_frame(model, 1, (6, 5), "ldr", blur=True)["ldr"]
    centred = render_frame(model, 1, (6, 5), "ldr", blur=True, centred=True)["ldr"]
    assert not np.allclose(centred, as_learned, atol=1e-4)
    model.blur.centre_exact = True
    np.testing.assert_allclose(render_frame(model, 1, (6, 5), "ldr", blur=True)["ldr"], centred, rtol=1e-6, atol=1e-7)
    model.blur.centre_exact = False
    full = render_frame(model, 2, (6, 5), ("ldr", "hdr"), blur=True, centred=True)
    for k in (2, 4):
        part = render_frame(model, 2, (6, 5), ("ldr", "hdr"), blur=True, centred=True, stride=k)
        assert part["ldr"].shape == (-(-6 // k), -(-5 // k), 3)
        for name in ("ldr", "hdr"):
            # the same pixels in other batches: float32 matmuls may block them differently (2.7e-6 seen)
            np.testing.assert_allclose(part[name], full[name][::k, ::k], rtol=1e-5, atol=1e-7)
