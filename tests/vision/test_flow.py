"""Tests for layercam.vision.flow (DIS flow across exposures, warping, consistency, global motion)."""

import numpy as np
import pytest

from layercam.vision import flow, flow_input, raft

from layercam import synth
from layercam.core.errors import LayercamError


def _epe_in_view(fw, gt):
    h, w = gt.shape[1:3]
    yy, xx = np.mgrid[0:h, 0:w]
    errs = []
    for t in range(len(gt)):
        x1, y1 = xx + gt[t][..., 0], yy + gt[t][..., 1]
        ins = (x1 >= 0) & (x1 <= w - 1) & (y1 >= 0) & (y1 <= h - 1)
        errs.append(np.linalg.norm(fw[t] - gt[t], axis=-1)[ins].mean())
    return float(np.mean(errs))


def test_normalise_for_flow_exposure_invariant():
    s = synth.pan_hdr(frames=1, size=(48, 48), seed=0)
    hdr = s.hdr[0]
    lo = synth.crf_apply(hdr * s.meta["gain"], "srgb")
    hi = synth.crf_apply(hdr * s.meta["gain"] * 8, "srgb")
    a, b = flow_input.normalise_for_flow(lo), flow_input.normalise_for_flow(hi)
    assert a.dtype == np.uint8 and a.shape == (48, 48)
    assert np.abs(a.astype(int) - b.astype(int)).mean() < 4
    ga, gb = flow_input.normalise_for_flow(lo, "grey"), flow_input.normalise_for_flow(hi, "grey")
    assert np.abs(ga.astype(int) - gb.astype(int)).mean() > 30
    with pytest.raises(LayercamError):
        flow_input.normalise_for_flow(lo, "nope")


@pytest.mark.parametrize("seed", [0, 1])
def test_dis_recovers_subpixel_motion_across_exposures(seed):
    s = synth.pan_hdr(frames=3, size=(64, 64), ev_step=3.0, seed=seed, zoom=0.0)
    gt = synth.true_flow(s)
    assert np.any(np.abs(gt - np.round(gt)) > 0.04)  # sub-pixel motion
    fw, bw = flow.compute_flow(s.frames, "dis_medium", progress=False)
    assert fw.shape == bw.shape == (2, 64, 64, 2) and fw.dtype == np.float32
    assert _epe_in_view(fw, gt) < 0.5
    gtb = -gt  # pure translation + small wobble: backward ~ -forward
    assert _epe_in_view(bw, gtb) < 0.6


def test_compute_flow_single_frame_and_errors():
    f = np.zeros((1, 16, 20, 3), np.float32)
    fw, bw = flow.compute_flow(f, progress=False)
    assert fw.shape == (0, 16, 20, 2) and bw.shape == (0, 16, 20, 2)
    with pytest.raises(LayercamError):
        flow.compute_flow(f, method="nope")
    with pytest.raises(LayercamError):
        flow.compute_flow(np.zeros((2, 16, 20)), progress=False)


def test_warp_convention():
    rng = np.random.default_rng(0)
    img = rng.uniform(0, 1, (20, 30, 3)).astype(np.float32)
    fl = np.zeros((20, 30, 2), np.float32)
    fl[..., 0] = 2.0
    fl[..., 1] = 1.0
    out = flow.warp(img, fl)
    assert out.shape == img.shape and out.dtype == img.dtype
    assert np.allclose(out[5, 5], img[6, 7])  # result(x) = img(x + flow(x))
    g = flow.warp(img[..., 0], fl)
    assert g.shape == (20, 30)
    fl[..., 0] = 0.5
    assert np.allclose(flow.warp(img, fl)[5, 5], 0.5 * (img[6, 5] + img[6, 6]), atol=1e-2)


def test_flow_consistency_masks_occlusion():
    h, w = 24, 24
    fw = np.zeros((1, h, w, 2), np.float32)
    fw[..., 0] = 3.0
    bw = -fw.copy()
    m = flow.flow_consistency(fw, bw)
    assert m.shape == (1, h, w)
    assert m[0, :, : w - 4].all() and not m[0, :, w - 2 :].any()  # leaves the view
    bw[0, 10:14, 10:14] = 5.0  # inconsistent patch (seen from frame t at x-3)
    m2 = flow.flow_consistency(fw, bw)
    assert not m2[0, 11:13, 8:10].any() and m2[0, 2, 2]


def test_homographies_and_residual_motion():
    h, w = 40, 48
    fw = np.zeros((2, h, w, 2), np.float32)
    fw[..., 0], fw[..., 1] = 1.5, -0.7
    fw[1, 10:20, 10:20] = (6.0, 4.0)  # an independently moving object
    hs = flow.global_homographies(fw)
    assert hs.shape == (2, 3, 3)
    assert np.allclose(hs[0], [[1, 0, 1.5], [0, 1, -0.7], [0, 0, 1]], atol=1e-3)
    assert np.allclose(hs[1][:2, 2], [1.5, -0.7], atol=1e-2)
    r = flow.residual_motion(fw, hs)
    assert r.shape == (2, h, w)
    assert r[0].max() < 1e-2 and r[1, 12:18, 12:18].min() > 4 and np.median(r[1]) < 1e-2


def test_raft_missing_weights(tmp_path):
    with pytest.raises(LayercamError):
        raft.raft_flow(np.zeros((2, 16, 16, 3), np.float32), str(tmp_path / "missing.pth"))
    with pytest.raises(LayercamError):
        flow.compute_flow(np.zeros((2, 16, 16, 3), np.float32), method="raft_small")


@pytest.mark.parametrize("method", ["dis_fast", "dis_medium"])
def test_small_frames_keep_a_moving_object(method):
    """On a 96x96 clip the DIS presets' coarse finest level (1/4 for dis_fast) lost an object that
    moves about 4.8 px against the background (0.5 px residual); the finest level is now kept at
    frame resolution there, so the analysis sees independent motion."""
    s = synth.moving_object(frames=4, size=(96, 96))
    fw, _ = flow.compute_flow(s.clip.frames, method=method, progress=False)
    res = flow.residual_motion(fw, flow.global_homographies(fw))
    obj = s.fg_mask[:-1].astype(bool)
    assert np.median(res[obj]) > 1.5
    assert np.median(res[~obj]) < 0.5


@pytest.mark.parametrize("hw", [(1, 1), (2, 3), (5, 7), (11, 40)])
def test_flow_on_frames_smaller_than_dis_patches(hw):
    from layercam.vision.flow import compute_flow

    frames = np.random.default_rng(0).random((3, *hw, 3)).astype(np.float32)
    fw, bw = compute_flow(frames, method="dis_fast", progress=False)
    assert fw.shape == bw.shape == (2, *hw, 2) and np.isfinite(fw).all() and np.isfinite(bw).all()


def test_working_size_scales_the_short_side_only_when_longer():
    from layercam.vision.scale import working_size

    assert working_size((1080, 1920), 540) == (540, 960)
    assert working_size((480, 854), 540) == (480, 854) and working_size((1080, 1920), 0) == (1080, 1920)


def test_flow_at_a_working_size_reads_back_at_the_frames_size():
    """A zoom-and-shift homography, measured on half-size frames, is the full-size one once rescaled;
    a half-size flow upsamples to the full-size flow of the same motion."""
    from layercam.vision.flow_store import at_frame_size
    from layercam.vision.scale import pixel_scaling, rescale_homographies

    full = np.array([[1.02, 0.0, 3.0], [0.0, 1.02, -2.0], [0.0, 0.0, 1.0]])
    a = pixel_scaling((20, 30), (40, 60))  # full-size pixels -> half-size pixels
    half = a @ full @ np.linalg.inv(a)
    assert np.allclose(rescale_homographies(half[None], (20, 30), (40, 60))[0], full)
    assert np.allclose(a @ [29.5, 19.5, 1.0], [14.5, 9.5, 1.0])  # the centres coincide

    def homography_flow(h, hw):
        yy, xx = np.mgrid[0 : hw[0], 0 : hw[1]].astype(np.float64)
        p = np.einsum("ij,jhw->ihw", h, np.stack([xx, yy, np.ones_like(xx)]))
        return np.stack([p[0] / p[2] - xx, p[1] / p[2] - yy], -1).astype(np.float32)

    fl = {"fw": homography_flow(half, (20, 30))[None], "fw_ok": np.ones((1, 20, 30), bool), "homs": half[None]}
    up = at_frame_size(fl, (40, 60))
    assert up["fw"].shape == (1, 40, 60, 2) and up["fw_ok"].shape == (1, 40, 60)
    inner = (slice(2, -2), slice(2, -2))
    assert np.abs(up["fw"][0][inner] - homography_flow(full, (40, 60))[inner]).max() < 0.05
    assert at_frame_size(fl, (40, 60), ("homs",)).keys() == {"homs"} and at_frame_size(fl, (20, 30)) is fl
