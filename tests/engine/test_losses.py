"""Tests of layercam.engine.losses: pure loss terms, finite on degenerate inputs; the one-sided colour loss
on clipped pixels."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, strategies as st
from hypothesis.extra import numpy as hnp

from layercam.engine import losses
from layercam.camera.tone import ToneMapper

from props import DTYPES, _finite, props


@props(40)
@given(
    pred=hnp.arrays(np.float32, (16, 3), elements=st.floats(0, 1, width=32)),
    target=hnp.arrays(np.float32, (16, 3),
                      elements=st.one_of(st.sampled_from([0.0, 1.0, 1 / 255, 254 / 255]),
                                         st.floats(0, 1, width=32))),
    dtype=DTYPES,
)
def test_color_loss_is_finite_and_the_robust_one_never_above_mse(pred, target, dtype):
    p, tg = torch.from_numpy(pred).to(dtype), torch.from_numpy(target).to(dtype)
    plain = losses.color_loss(p, tg)
    robust = losses.color_loss(p, tg, robust=0.05)
    assert _finite(plain, robust) and float(robust) >= 0
    assert float(robust) <= float(plain) + 1e-7  # c^2 ln(1 + x / c^2) <= x


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
    assert float(losses.mask_loss(moved, mask,
                                  keep=keep)) == pytest.approx(float(losses.mask_loss(alpha, mask,
        keep=keep)))
    assert float(losses.mask_loss(alpha[keep],
                                  mask[keep])) == pytest.approx(float(losses.mask_loss(alpha, mask,
        keep=keep)))
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
