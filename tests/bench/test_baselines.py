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


def _shaky_clip(n=5, size=48, seed=3):
    """A textured scene panning 1 px a frame; frame 2 sharp, the others box-blurred along x."""
    import cv2

    rng = np.random.default_rng(seed)
    scene = cv2.GaussianBlur(rng.random((size, size + n + 8, 3)).astype(np.float32), (0, 0), 1.0)
    sharp = np.stack([scene[:, t : t + size] for t in range(n)])
    blurry = np.stack([s if t == 2 else cv2.blur(s, (7, 1)) for t, s in enumerate(sharp)])
    return sharp, blurry


def test_lucky_regions_takes_the_sharp_neighbour_in_each_frames_view():
    sharp, blurry = _shaky_clip()
    out = baselines.lucky_regions(blurry, radius=2)
    assert out.shape == blurry.shape and out.dtype == np.float32
    c = slice(6, -6)  # away from the borders the flow cannot see past
    gain = [metrics.ldr_metrics(out[t][c, c], sharp[t][c, c])["psnr"]
            - metrics.ldr_metrics(blurry[t][c, c], sharp[t][c, c])["psnr"] for t in (1, 3)]
    assert min(gain) > 1.0, gain  # the sharp frame 2, warped into frames 1 and 3
    assert np.allclose(out[2][c, c], blurry[2][c, c], atol=0.02)  # the sharpest frame keeps itself


def test_unsharp_mask_steepens_edges_and_stays_in_range():
    _, blurry = _shaky_clip()
    out = baselines.unsharp_mask(blurry, sigma=1.5, amount=1.0)
    assert out.shape == blurry.shape and out.min() >= 0 and out.max() <= 1
    assert np.abs(np.diff(out, axis=2)).mean() > np.abs(np.diff(blurry, axis=2)).mean()
