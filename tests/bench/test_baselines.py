"""Tests for layercam.bench.baselines (classical HDR / focus-fusion comparisons)."""

import numpy as np
import pytest

from layercam.bench import baselines

from layercam.vision import flow

from layercam.core import metrics

from layercam import synth
from layercam.core.errors import LayercamError


@pytest.fixture(scope="module")
def pan():
    return synth.pan_hdr(frames=6, size=(48, 48), ev_step=3.0, seed=1)


def test_debevec_video_beats_trivial(pan):
    hdr = baselines.debevec_video(pan.frames, pan.exposure_times)
    assert hdr.shape == pan.frames.shape and hdr.dtype == np.float32
    assert np.all(np.isfinite(hdr)) and hdr.min() >= 0
    trivial = synth.crf_inverse(pan.frames, "gamma") / pan.exposure_times[:, None, None, None]
    d, t = metrics.hdr_metrics(hdr, pan.hdr), metrics.hdr_metrics(trivial, pan.hdr)
    assert d["psnr_mu"] > t["psnr_mu"] + 3
    assert d["psnr_l"] > t["psnr_l"] + 5


def test_debevec_video_given_flows_and_fallback(pan):
    fw, bw = flow.compute_flow(pan.frames[:3], progress=False)
    a = baselines.debevec_video(pan.frames[:3], pan.exposure_times[:3], fw, bw)
    assert a.shape == (3, 48, 48, 3) and np.all(np.isfinite(a))
    single = baselines.debevec_video(pan.frames[:3], np.ones(3))
    assert np.all(np.isfinite(single))
    with pytest.raises(LayercamError):
        baselines.debevec_video(pan.frames[:1], [1.0])
    with pytest.raises(LayercamError):
        baselines.debevec_video(pan.frames[:3], [1.0, 2.0])
    with pytest.raises(LayercamError):
        baselines.debevec_video(pan.frames[:3], [1.0, 0.0, 2.0])


@pytest.fixture(scope="module")
def mfme():
    return synth.mfme_stack(size=(48, 48), seed=0)


def test_laplacian_focus_fusion(mfme):
    sel = mfme.meta["exposure_index"] == 1
    fused = baselines.laplacian_focus_fusion(mfme.frames[sel])
    assert fused.shape == (48, 48, 3)
    ref = mfme.sharp_ldr[np.flatnonzero(sel)[0]]
    best_input = max(metrics.psnr(f, ref) for f in mfme.frames[sel])
    assert metrics.psnr(fused, ref) > best_input + 1
    hard = baselines.laplacian_focus_fusion(mfme.frames[sel], soft=False)
    assert np.all(np.isfinite(hard))


def test_two_stage_mfme(mfme):
    out = baselines.two_stage_mfme(mfme.frames, mfme.exposure_times, mfme.meta["focus_index"])
    assert out.shape == (48, 48, 3) and np.all(np.isfinite(out))
    single = synth.crf_inverse(mfme.frames[4], "gamma")  # one blurry middle exposure
    assert metrics.psnr_mu(out, mfme.allfocus_hdr) > metrics.psnr_mu(single, mfme.allfocus_hdr) + 2
    with pytest.raises(LayercamError):
        baselines.two_stage_mfme(mfme.frames, mfme.exposure_times, np.zeros(9, int))
