"""Tests for layercam.core.metrics."""

import numpy as np
import pytest

from layercam.core import frame_metrics, metrics
from layercam.core.errors import LayercamError


def _hdr(seed=0, shape=(2, 24, 24, 3)):
    rng = np.random.default_rng(seed)
    return np.exp(rng.normal(0, 1.5, shape)).astype(np.float32)


def test_psnr_identical_finite_and_known_value():
    a = np.random.default_rng(0).uniform(0, 1, (16, 16, 3))
    assert metrics.psnr(a, a) == metrics.PSNR_CAP
    b = np.clip(a + 0.1, None, None)
    assert metrics.psnr(b, a) == pytest.approx(20.0, abs=1e-6)
    assert metrics.psnr_mu(a, a) == metrics.PSNR_CAP and np.isfinite(metrics.psnr_l(a, a))


def test_align_scale_recovers_per_channel_scale():
    gt = _hdr()
    s = np.array([2.0, 0.5, 7.0], np.float32)
    pred = gt / s
    al = metrics.align_scale(pred, gt)
    assert np.allclose(al, gt, rtol=1e-4)
    # robust to a few outliers
    pred2 = pred.copy()
    pred2[0, :3] *= 100
    assert np.allclose(metrics.align_scale(pred2, gt)[1], gt[1], rtol=1e-3)


def test_align_scale_valid_mask_and_zeros():
    gt = _hdr(1, (16, 16, 3))
    pred = gt * 3
    pred[:8] = 0.0
    valid = np.zeros((16, 16), bool)
    valid[8:] = True
    assert np.allclose(metrics.align_scale(pred, gt, valid)[8:], gt[8:], rtol=1e-4)
    out = metrics.align_scale(np.zeros_like(gt), gt)
    assert np.all(np.isfinite(out))


def test_psnr_mu_invariant_to_channel_scale():
    gt = _hdr(2)
    noisy = gt * np.exp(np.random.default_rng(3).normal(0, 0.05, gt.shape)).astype(np.float32)
    p1 = metrics.psnr_mu(noisy, gt)
    p2 = metrics.psnr_mu(noisy * np.array([0.1, 3.0, 40.0], np.float32), gt)
    assert p1 == pytest.approx(p2, abs=1e-3)
    assert 20 < p1 < 80
    l1, l2 = metrics.psnr_l(noisy, gt), metrics.psnr_l(noisy * 9.0, gt)
    assert l1 == pytest.approx(l2, abs=1e-3)
    # without alignment the scale matters
    assert metrics.psnr_mu(noisy * 9.0, gt, align=False) < p1 - 3


def test_mu_law_endpoints():
    assert metrics.mu_law(0.0) == 0.0
    assert metrics.mu_law(1.0) == pytest.approx(1.0)
    assert metrics.mu_law(0.01) == pytest.approx(np.log(51) / np.log(5001))


def test_ssim_and_bundles():
    gt = _hdr(4, (2, 20, 20, 3))
    ldr = np.clip(gt / gt.max(), 0, 1)
    assert metrics.ssim(ldr, ldr) == pytest.approx(1.0, abs=1e-4)
    assert metrics.ssim(ldr[0], ldr[0]) == pytest.approx(1.0, abs=1e-4)
    noisy = np.clip(ldr + np.random.default_rng(0).normal(0, 0.1, ldr.shape), 0, 1)
    assert metrics.ssim(noisy, ldr) < 0.95
    d = metrics.hdr_metrics(gt * 0.3, gt)
    assert set(d) == {"psnr_mu", "psnr_l", "ssim_mu"} and all(np.isfinite(list(d.values())))
    assert d["ssim_mu"] == pytest.approx(1.0, abs=1e-4)
    e = metrics.ldr_metrics(noisy, ldr)
    assert set(e) == {"psnr", "ssim"} and 10 < e["psnr"] < 30
    assert all(isinstance(v, float) for v in list(d.values()) + list(e.values()))


def test_guards():
    gt = _hdr(5, (8, 8, 3))
    bad = gt.copy()
    bad[0, 0, 0] = np.nan
    for fn in (metrics.psnr, metrics.psnr_mu, metrics.psnr_l, metrics.ssim, metrics.align_scale):
        with pytest.raises(ValueError):
            fn(bad, gt)
    with pytest.raises(LayercamError):
        metrics.psnr(gt[:4], gt)
    # NaN/inf in gt is left out, results finite
    gt2 = gt.copy()
    gt2[1, 1] = np.inf
    assert np.isfinite(metrics.psnr_mu(gt, gt2)) and np.isfinite(metrics.psnr(gt, gt2))
    # zero prediction against positive gt: finite
    assert np.isfinite(metrics.psnr_mu(np.zeros_like(gt), gt))
    with pytest.raises(ValueError):
        metrics.psnr_mu(gt, np.zeros_like(gt))


def test_iou():
    a = np.zeros((4, 4), bool)
    b = np.zeros((4, 4), bool)
    assert metrics.iou(a, b) == 1.0
    a[:2] = True
    b[1:3] = True
    assert metrics.iou(a, b) == pytest.approx(4 / 12)
    with pytest.raises(ValueError):
        metrics.iou(a, b[:2])


def test_highlight_psnr_mu_restricts_psnr_mu_to_the_mask():
    from layercam.core import metrics

    rng = np.random.default_rng(0)
    gt = rng.random((2, 8, 8, 3)).astype(np.float32) * 4
    pred = gt.copy()
    pred[:, :2] *= 1.3  # wrong only in the top quarter (the median alignment keeps the rest exact)
    top = np.zeros((2, 8, 8), bool)
    top[:, :2] = True
    assert metrics.highlight_psnr_mu(pred, gt, np.ones_like(top)) == pytest.approx(metrics.psnr_mu(pred, gt))
    assert metrics.highlight_psnr_mu(pred, gt, top) < metrics.psnr_mu(pred,
                                     gt) < metrics.highlight_psnr_mu(pred, gt, ~top)
    with pytest.raises(metrics.MetricInputError):
        metrics.highlight_psnr_mu(pred, gt, np.zeros_like(top))


# -- the DeepHDRVideo protocol ------------------------------------------------------------------
def test_deephdr_known_values():
    """A quarter of the pixels twice too bright (the median ratio stays 1, so no rescaling)."""
    gt = np.full((16, 16, 3), 0.25)
    pred = gt.copy()
    pred[:8, :8] = 0.5
    d = frame_metrics.deephdr_metrics(pred, gt)
    assert d["psnr_l"] == pytest.approx(-10 * np.log10(0.25 * 0.25**2), abs=1e-6)
    mu_err = (np.log1p(5000 * 0.5) - np.log1p(5000 * 0.25)) / np.log1p(5000)
    assert d["psnr_t"] == pytest.approx(-10 * np.log10(0.25 * mu_err**2), abs=1e-6)
    assert 0 < d["ssim_t"] < 1
    same = frame_metrics.deephdr_metrics(gt, gt)
    assert same["psnr_t"] == metrics.PSNR_CAP and same["ssim_t"] == pytest.approx(1.0, abs=1e-6)


def test_deephdr_one_scale_for_all_channels_and_gt_normalised_when_above_one():
    gt = _hdr(4, (20, 20, 3))
    gt = gt / (2 * gt.max())
    noisy = gt * np.exp(np.random.default_rng(5).normal(0, 0.1, gt.shape)).astype(np.float32)
    d = frame_metrics.deephdr_metrics(noisy, gt)
    # the prediction's overall scale is free, a colour cast is not (unlike psnr_mu's per-channel scale)
    assert frame_metrics.deephdr_metrics(noisy * 7.0, gt)["psnr_t"] == pytest.approx(d["psnr_t"], abs=1e-4)
    cast = noisy * np.array([1.0, 2.0, 1.0], np.float32)
    assert frame_metrics.deephdr_metrics(cast, gt)["psnr_t"] < d["psnr_t"] - 3
    assert metrics.psnr_mu(cast, gt) == pytest.approx(metrics.psnr_mu(noisy, gt), abs=1e-3)
    # a ground truth above 1 is divided by its max; one already in [0, 1] is kept as it is
    k = 0.5 / gt.max()
    big = frame_metrics.deephdr_metrics(noisy * 10 * k, gt * 10 * k)  # gt max 5 -> divided by 5
    assert big["psnr_t"] == pytest.approx(frame_metrics.deephdr_metrics(noisy * 2 * k, gt * 2 * k)["psnr_t"], abs=1e-4)
    assert big["psnr_t"] != pytest.approx(frame_metrics.deephdr_metrics(noisy * k, gt * k)["psnr_t"], abs=0.1)


def test_deephdr_averages_per_frame():
    gt = _hdr(6, (2, 12, 12, 3))
    pred = gt.copy()
    pred[1] *= np.exp(np.random.default_rng(7).normal(0, 0.2, pred[1].shape)).astype(np.float32)
    both = frame_metrics.deephdr_metrics(pred, gt)
    f0, f1 = frame_metrics.deephdr_metrics(pred[0], gt[0]), frame_metrics.deephdr_metrics(pred[1], gt[1])
    assert both["psnr_t"] == pytest.approx((f0["psnr_t"] + f1["psnr_t"]) / 2, abs=1e-6)
    assert f0["psnr_t"] == metrics.PSNR_CAP


def test_hdr_metrics_streamed_matches_the_stacked_clip():
    """Frame by frame (for 1080p clips) gives hdr_metrics' numbers on the whole clip."""
    gt = _hdr(11, (3, 16, 20, 3))
    pred = gt * np.array([0.5, 0.7, 0.9]) * np.exp(np.random.default_rng(1).normal(0, 0.2, gt.shape))
    want = metrics.hdr_metrics(pred, gt)
    got = frame_metrics.hdr_metrics_streamed(lambda t: pred[t], lambda t: gt[t], 3)
    assert set(got) == set(want)
    for k in want:
        assert got[k] == pytest.approx(want[k], abs=1e-3), k
    with pytest.raises(LayercamError):
        frame_metrics.hdr_metrics_streamed(lambda t: pred[t], lambda t: gt[t], 0)
