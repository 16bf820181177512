"""Tests of layercam.losses: pure loss terms, finite on degenerate inputs; the one-sided colour loss
on clipped pixels."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, strategies as st
from hypothesis.extra import numpy as hnp

from layercam import losses
from layercam.camera.tone import ToneMapper
from layercam.config import load_config
from layercam.io import Exposures, read_exr
from layercam.pipelines.tasks import run_task

from props import DTYPES, _finite, props


def test_one_sided_loss_measures_clipped_pixels_against_the_threshold():
    from layercam import losses

    target = torch.tensor([[1.0, 0.0, 0.5]])
    # a sigmoid curve never reaches 1: past the threshold a clipped pixel is satisfied
    assert float(losses.color_loss(torch.tensor([[0.998, 0.003, 0.5]]), target, "one_sided")) == 0.0
    # on the wrong side of the threshold it still costs (and plain MSE always does)
    assert float(losses.color_loss(torch.tensor([[0.9, 0.003, 0.5]]), target, "one_sided")) > 0
    assert float(losses.color_loss(torch.tensor([[0.998, 0.003, 0.5]]), target, "plain")) > 0


@pytest.mark.slow
def test_one_sided_loss_improves_clipped_highlights(tmp_path):
    """synth.pan_hdr at +5 EV (29% of the pixels clip in the long exposure), fast preset: PSNR-mu over
    the pixels clipped in some exposure, plain MSE against the one-sided loss (measured: 32.6 -> 33.8 dB)."""
    from layercam import metrics, synth

    scene = synth.pan_hdr(frames=8, size=(64, 64), ev_step=5.0, seed=0)
    log2 = np.log2(scene.exposure_times / scene.exposure_times.min())
    ex = Exposures(log2, "none", np.arange(8) % 2, "alt", "test")
    white = 1.0 / (scene.meta["gain"] * scene.exposure_times.max())
    clipped = (scene.hdr >= white).any(-1)
    hl = {}
    for mode in ("plain", "one_sided"):
        cfg = load_config("fast", ["flow.method=dis_fast", f"loss.clipped={mode}"])
        run_task("hdr-video", scene.clip, ex, cfg, tmp_path / mode, progress=False)
        pred = np.stack([read_exr(tmp_path / mode / "hdr" / f"frame_{t:05d}.exr") for t in range(8)])
        hl[mode] = metrics.highlight_psnr_mu(pred, scene.hdr, clipped)
    assert hl["one_sided"] > hl["plain"] + 0.5, hl


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


def test_mask_loss_counts_only_the_pixels_it_keeps():
    g = torch.Generator().manual_seed(0)
    alpha, mask = torch.rand(256, 1, generator=g), (torch.rand(256, generator=g) > 0.8).float()
    keep = torch.rand(256, generator=g) > 0.5
    moved = alpha.clone()
    moved[~keep] = 1.0 - moved[~keep]  # alpha changed only where it is not kept
    assert float(losses.mask_loss(moved, mask, keep=keep)) == pytest.approx(float(losses.mask_loss(alpha, mask, keep=keep)))
    assert float(losses.mask_loss(alpha[keep], mask[keep])) == pytest.approx(float(losses.mask_loss(alpha, mask, keep=keep)))
    assert float(losses.mask_loss(alpha, mask, keep=torch.zeros(256, dtype=torch.bool))) == 0.0


def test_mask_loss_balanced_puts_a_halo_around_a_small_object_plain_does_not():
    """A small object (60 of 1000 samples labelled object) and 200 samples of one ambiguous pixel,
    40 of them (20%) labelled object: the alpha minimising the plain loss there is 0.2, the
    class-balanced one's (object samples weigh 10) is above 0.5."""
    mask = torch.zeros(1000)
    mask[:20] = 1.0     # the object
    mask[100:140] = 1.0  # 40 of the ambiguous pixel's 200 samples (100..299)
    grid = torch.linspace(0.02, 0.98, 49)

    def best(balance):
        def loss(a):
            alpha = torch.full((1000, 1), 0.01)
            alpha[:20] = 0.99
            alpha[100:300] = a
            return float(losses.mask_loss(alpha, mask, balance))

        return float(grid[int(np.argmin([loss(a) for a in grid]))])

    assert best(0.0) == pytest.approx(0.2, abs=0.02)
    assert best(1.0) > 0.5
    assert best(0.0) < best(0.5) < best(1.0)


def test_robust_colour_loss_is_mse_for_small_errors_and_grows_slowly_past_its_scale():
    """``loss.robust = c``: the Cauchy loss ``c^2 ln(1 + (e/c)^2)``, ``e^2`` for errors well under
    ``c`` (noise is fitted as under MSE) and far less than ``e^2`` past it (a shot where the scene
    changed pulls the shared tone curve much less); its gradient falls past ``c``."""
    target = torch.zeros(4, 3)
    small = torch.full((4, 3), 0.005)
    assert torch.allclose(losses.color_loss(small, target, robust=0.05), losses.color_loss(small, target), rtol=0.01)
    big = torch.full((4, 3), 0.3)
    assert losses.color_loss(big, target, robust=0.05) < 0.2 * losses.color_loss(big, target)  # 0.009 against 0.09
    grads = []
    for e in (0.05, 0.3):
        p = torch.full((1, 3), e, requires_grad=True)
        losses.color_loss(p, torch.zeros(1, 3), robust=0.05).backward()
        grads.append(float(p.grad[0, 0]))
    assert grads[1] < grads[0]  # past the scale a larger error pulls less
    # one-sided clipping still applies first: a clipped target above the prediction costs nothing
    assert float(losses.color_loss(torch.ones(2, 3), torch.ones(2, 3), mode="one_sided", robust=0.05)) == 0.0
