"""Tests for layercam.synth: determinism, shapes, ranges, exposure/clipping, blur, geometry."""

import numpy as np
import pytest

from layercam import synth
from layercam.core.errors import LayercamError

SMALL = {
    "pan_hdr": dict(frames=4, size=(40, 48)),
    "static_single": dict(frames=3, size=(32, 32)),
    "moving_object": dict(frames=4, size=(48, 48)),
    "shake_blur": dict(frames=4, size=(40, 40), max_blur_px=6),
    "mfme_stack": dict(size=(48, 40)),
}


@pytest.mark.parametrize("family", synth.FAMILIES)
def test_deterministic_shapes_ranges(family):
    a = synth.make(family, seed=3, **SMALL[family])
    b = synth.make(family, seed=3, **SMALL[family])
    c = synth.make(family, seed=4, **SMALL[family])
    assert np.array_equal(a.frames, b.frames) and np.array_equal(a.hdr, b.hdr)
    assert not np.array_equal(a.frames, c.frames)
    t, h, w, ch = a.frames.shape
    assert ch == 3 and a.hdr.shape == a.frames.shape and a.exposure_times.shape == (t,)
    assert a.clip.source == f"synthetic:{family}" and len(a.clip.names) == t
    assert a.frames.dtype == np.float32 and a.frames.min() >= 0 and a.frames.max() <= 1
    q = a.frames * 255.0
    assert np.allclose(q, np.round(q), atol=1e-3)  # 8-bit quantised
    assert np.all(np.isfinite(a.hdr)) and a.hdr.min() > 0
    assert np.all(a.exposure_times > 0)
    assert a.meta["family"] == family and a.crf in synth.CRFS


def test_sizes_are_h_w():
    s = synth.pan_hdr(frames=2, size=(40, 56))
    assert s.frames.shape == (2, 40, 56, 3)


@pytest.mark.parametrize("name", synth.CRFS)
def test_crf_roundtrip_monotone(name):
    x = np.linspace(0, 1, 301, dtype=np.float32)
    x3 = np.repeat(x[:, None], 3, axis=1)
    y = synth.crf_apply(x3, name)
    assert abs(float(y.min())) < 1e-6 and abs(float(y.max()) - 1) < 1e-6
    assert np.all(np.diff(y, axis=0) >= 0)
    assert np.allclose(synth.crf_inverse(y, name), x3, atol=2e-4)
    assert np.array_equal(synth.crf_apply(x3 * 5, name)[-1], synth.crf_apply(x3, name)[-1])


def test_crf_mixed_differs_per_channel_and_bad_name():
    y = synth.crf_apply(np.full((4, 3), 0.05), "mixed")
    assert np.ptp(y[0]) > 0.01
    with pytest.raises(LayercamError):
        synth.crf_apply(np.zeros(3), "nope")


def test_pan_hdr_clipping_and_dynamic_range():
    s = synth.pan_hdr(frames=6, size=(64, 64), ev_step=3.0, seed=1)
    assert np.allclose(s.exposure_times, [1, 8, 1, 8, 1, 8])
    clipped = (s.frames >= 1.0).any(-1).mean(axis=(1, 2))
    assert np.all(clipped[1::2] > 0.001)  # high exposures clip the emitters
    assert np.all(clipped[0::2] < clipped[1::2])
    assert np.all(clipped[0::2] < 0.002)  # low exposure keeps them (mostly) unclipped
    # emitters at least 4 stops above the background
    med = np.median(s.hdr)
    assert s.hdr.max() / med >= 16
    # high exposure shows shadows brighter
    assert np.median(s.frames[1]) > np.median(s.frames[0]) + 0.1


def test_true_flow_matches_warp():
    from layercam.vision.flow import warp

    s = synth.pan_hdr(frames=3, size=(48, 48), seed=2)
    gt = synth.true_flow(s)
    assert gt.shape == (2, 48, 48, 2)
    assert 0.5 < np.linalg.norm(gt[0], axis=-1).mean() < 6
    err = np.abs(warp(s.hdr[1], gt[0]) - s.hdr[0])[6:-6, 6:-6]
    base = np.abs(s.hdr[1] - s.hdr[0])[6:-6, 6:-6]
    assert np.median(err) < 0.3 * np.median(base)


def test_moving_object_mask_moves():
    s = synth.moving_object(frames=5, size=(64, 64), seed=0)
    assert s.fg_mask.shape == (5, 64, 64) and s.fg_mask.dtype == bool
    frac = s.fg_mask.mean(axis=(1, 2))
    assert np.all(frac > 0.03) and np.all(frac < 0.4)
    cy = [np.argwhere(m).mean(0) for m in s.fg_mask]
    assert np.linalg.norm(cy[-1] - cy[0]) > 2
    gt = synth.true_flow(s)
    assert np.abs(gt[0][s.fg_mask[0]].mean(0) - gt[0][~s.fg_mask[0]].mean(0)).max() > 0.3


def _lap_map(img):
    g = img.mean(-1)
    return (g[1:-1, :-2] + g[1:-1, 2:] + g[:-2, 1:-1] + g[2:, 1:-1] - 4 * g[1:-1, 1:-1]) ** 2


def _lap_energy(img):
    return float(_lap_map(img).mean())


def test_shake_blur_blurred():
    s = synth.shake_blur(frames=6, size=(64, 64), max_blur_px=8, seed=0)
    assert s.sharp_ldr.shape == s.frames.shape
    L = s.meta["blur_length"]
    assert L.min() < 2 and L.max() > 6
    k = s.meta["kernels"]
    assert np.allclose(k.sum(axis=(1, 2)), 1, atol=1e-5)
    i = int(np.argmax(L))
    assert _lap_energy(s.frames[i]) < 0.6 * _lap_energy(s.sharp_ldr[i])
    blurred = np.mean([_lap_energy(f) for f in s.frames])
    assert blurred < np.mean([_lap_energy(f) for f in s.sharp_ldr])
    assert np.all(s.exposure_times == 1)


def test_mfme_stack_layout():
    s = synth.mfme_stack(size=(64, 64), focus_settings=3, exposures_ev=(0, 2, 4), seed=0)
    assert s.frames.shape == (9, 64, 64, 3) and s.allfocus_hdr.shape == (64, 64, 3)
    assert s.meta["order"] == "focus-major"
    assert list(s.meta["focus_index"]) == [0, 0, 0, 1, 1, 1, 2, 2, 2]
    assert list(s.meta["ev"]) == [0, 2, 4] * 3
    assert np.allclose(s.exposure_times, 2.0 ** s.meta["ev"])
    assert np.array_equal(s.hdr[4], s.allfocus_hdr)
    near = s.meta["depth"] == min(s.meta["plane_depths"])
    assert near.mean() > 0.05
    # focus on the near plane (focus index 2) is sharper there than focus on the far plane (0)
    inner = near.copy()
    for _ in range(6):  # erode: measure inside the near plane, away from its boundary
        inner[1:-1, 1:-1] &= inner[:-2, 1:-1] & inner[2:, 1:-1] & inner[1:-1, :-2] & inner[1:-1, 2:]
    inner = inner[1:-1, 1:-1]
    e_far, e_near = _lap_map(s.frames[1])[inner].mean(), _lap_map(s.frames[7])[inner].mean()
    assert inner.sum() > 20 and e_near > 2 * e_far
    assert s.meta["blur_radius"].max() == pytest.approx(5.0, abs=1e-4)


def test_make_errors():
    with pytest.raises(LayercamError):
        synth.make("nope")
    with pytest.raises(LayercamError):
        synth.make("pan_hdr", bogus=1)
    with pytest.raises(LayercamError):
        synth.make("pan_hdr", frames=0)


def test_pan_hdr_frames_one_at_a_time_are_pan_hdr():
    s = synth.pan_hdr(frames=4, size=(24, 32), seed=3)
    meta, times, each = synth.pan_hdr_frames(frames=4, size=(24, 32), seed=3)
    pairs = list(each)
    assert np.array_equal(times, s.exposure_times) and meta["gain"] == s.meta["gain"]
    assert all(np.array_equal(h, s.hdr[t]) and np.array_equal(l, s.clip.frames[t]) for t, (h, l) in enumerate(pairs))


def test_clip_on_disk_is_the_clip_with_its_truth(tmp_path):
    """synth.disk writes the user's view (8-bit PNGs, times.txt) and the linear truth, frame by frame."""
    from layercam.io import read_image
    from layercam.synth.disk import main, truth_frame

    assert main([str(tmp_path / "c"), "--size", "24x32", "--frames", "3", "--seed", "3"]) == 0
    s = synth.pan_hdr(frames=3, size=(24, 32), seed=3)
    for t in range(3):
        assert np.array_equal(truth_frame(tmp_path / "c", t), s.hdr[t])
        png = read_image(tmp_path / "c" / "frames" / f"frame_{t:05d}.png")
        assert png.shape == (24, 32, 3) and np.abs(png - s.clip.frames[t]).max() <= 0.5 / 255 + 1e-6
    lines = (tmp_path / "c" / "times.txt").read_text().split()
    assert [float(v) for v in lines[1::2]] == pytest.approx(list(s.exposure_times))
