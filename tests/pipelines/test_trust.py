"""The sharp export's per-pixel trust (``pipelines/view.py``) on tiny synthetic scenes: a sharp
texture, a camera blur, the input's noise, and a "model" that holds part of it."""

from __future__ import annotations

import numpy as np

NOISE = 0.004  # the input's noise (about one code)


def _scene(blur: int = 5, size: int = 96, seed: int = 0):
    """``(sharp, input, camera)``: detail at 1-2 px, the input its box blur of ``blur`` px plus noise."""
    import cv2

    rng = np.random.default_rng(seed)
    sharp = 0.2 + 0.6 * cv2.GaussianBlur(rng.random((size, size, 3)).astype(np.float32), (0, 0), 1.0)
    # a real texture's contrast
    sharp = np.clip(0.5 + (sharp - sharp.mean()) * (0.2 / sharp.std()), 0, 1).astype(np.float32)
    camera = lambda im: cv2.blur(np.asarray(im, np.float32), (blur, blur))  # noqa: E731
    frame = np.clip(camera(sharp) + rng.normal(0, NOISE, sharp.shape), 0, 1).astype(np.float32)
    return sharp, frame, camera


def _psnr(a, b) -> float:
    return float(10 * np.log10(1.0 / np.mean((np.asarray(a, np.float64) - b) ** 2)))


def test_a_region_the_model_holds_is_written_sharp_and_one_it_cannot_from_the_input():
    from layercam.pipelines.view import blend, trust

    sharp, frame, camera = _scene()
    model = sharp.copy()
    model[32:64, 32:64] = np.roll(sharp, 6, axis=1)[32:64, 32:64]  # a limb the layers hold 6 px away
    sigma = 2.0
    mask, info = trust(camera(model), frame, sigma)  # the model re-blurred: its blur is the camera's
    out = blend(model, frame, mask)
    assert mask.shape == frame.shape[:2] and 0.0 <= mask.min() and mask.max() <= 1.0
    held = np.ones(mask.shape, bool)
    held[32 - 12 : 64 + 12, 32 - 12 : 64 + 12] = False  # 6 sigma from the region the model misses
    held[:6], held[-6:], held[:, :6], held[:, -6:] = False, False, False, False  # (the box blur's border)
    assert mask[held].mean() > 0.85, mask[held].mean()
    assert mask[40:56, 40:56].max() < 0.05  # inside the missed region: the input
    assert _psnr(out[held], sharp[held]) > _psnr(frame[held], sharp[held]) + 3  # sharper where held
    assert np.abs(out[40:56, 40:56] - frame[40:56, 40:56]).max() < 0.02  # the input, as it came
    assert abs(info["noise"][0] - NOISE * 255) < 0.6  # the input's own noise, measured on it
    assert _psnr(out, sharp) > max(_psnr(frame, sharp), _psnr(model, sharp))  # better than either alone


def test_the_blend_has_no_seam():
    """From the region the model holds to the one it does not, the mask ramps over the window (no
    step from one pixel to the next), so the written frame has no edge the two images lack."""
    from layercam.pipelines.view import blend, trust

    sharp, frame, camera = _scene()
    model = sharp.copy()
    model[:, 48:] = sharp[::-1][:, 48:]  # the right half: other content
    for sigma in (2.0, 4.0):
        mask, _ = trust(camera(model), frame, sigma)
        row = mask[40:56].mean(0)
        assert row[:20].min() > 0.8 and row[-20:].max() < 0.05
        step = np.abs(np.diff(mask, axis=1)).max()
        assert step < 0.4 / sigma, (sigma, step)  # a hard mask steps by 1 at the seam
        ramp = ((mask[40:56] > 0.1) & (mask[40:56] < 0.9)).sum(1)
        assert ramp.min() >= sigma  # intermediate values over at least the window's width
        out = blend(model, frame, mask)
        jump = np.abs(np.diff(out, axis=1)).max(-1)[8:-8, 40:60]  # the seam's columns
        both = np.maximum(np.abs(np.diff(model, axis=1)).max(-1), np.abs(np.diff(frame, axis=1)).max(-1))[8:-8, 40:60]
        assert (jump <= both + 0.4 / sigma * np.abs(model - frame)[8:-8, 40:60].max(-1) + 1e-3).all()


def test_a_frame_with_the_wrong_high_frequencies_is_refused_though_its_low_pass_matches():
    """The per-frame check this replaces compared low-passes (Gaussian sigma 4 px, 30 dB): a frame
    whose detail is another texture's passed it. The re-blurred model against the input reads
    every frequency the input holds."""
    import cv2

    from layercam.pipelines.view import trust

    sharp, frame, camera = _scene(blur=3)  # a small blur: the input keeps much of the detail
    low = lambda im: cv2.GaussianBlur(np.asarray(im, np.float32), (0, 0), 2.0)  # noqa: E731
    other, _, _ = _scene(blur=3, seed=1)
    model = low(sharp) + (other - low(other))  # its low-pass, another texture's detail
    lowpass_db = _psnr(cv2.GaussianBlur(model, (0, 0), 4.0), cv2.GaussianBlur(frame, (0, 0), 4.0))
    assert lowpass_db > 30.0  # what the old check passed
    mask, info = trust(camera(model), frame, 2.0)
    assert info["kept"] < 0.1 and mask[8:-8, 8:-8].max() < 0.3, info
    right, _ = trust(camera(sharp), frame, 2.0)  # the true sharp frame passes
    assert right[8:-8, 8:-8].mean() > 0.85


def test_the_check_read_every_other_pixel_agrees_with_every_pixel():
    """At a window of 4 px the re-blurred render is read every 2nd pixel (``check_stride``): the
    mask is the full one within its own window's noise."""
    from layercam.pipelines.view import check_stride, trust

    sharp, frame, camera = _scene()
    model = sharp.copy()
    model[20:50, 30:70] = np.roll(sharp, 5, axis=0)[20:50, 30:70]
    d = check_stride(4.0)
    assert d == 2 and check_stride(2.0) == 1
    full, _ = trust(camera(model), frame, 4.0)
    part, _ = trust(camera(model)[::d, ::d], frame, 4.0, d)
    assert part.shape == full.shape
    assert np.abs(part - full)[8:-8, 8:-8].mean() < 0.03 and np.abs(part - full).max() < 0.3
