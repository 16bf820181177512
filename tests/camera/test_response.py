"""Tests of layercam.camera.response: the response measured from matched pixels of two exposures
recovers a known camera curve (Debevec-Malik), from codes the flow matches between shifted frames,
and the tone mapper starts on it."""

from __future__ import annotations

import numpy as np
import torch

from layercam.camera.response import fit_response, matched_codes
from layercam.camera.tone import ToneMapper, fit_init_curve
from layercam.vision.flow_store import FlowArrays


def camera(e: np.ndarray) -> np.ndarray:
    """A camera that is none of the tone mapper's starts: gamma 1/2.2 with a soft knee, clipped, 8 bits.
    ``e``: exposure with ``camera(1) = 0.5``."""
    x = 0.5 ** 2.2 * e
    c = np.clip(x, 0, None) ** (1 / 2.2)
    c = np.where(c > 0.8, 0.8 + 0.2 * np.tanh((c - 0.8) / 0.2), c)
    return np.round(np.clip(c, 0, 1) * 255) / 255


def truth_g(codes: np.ndarray) -> np.ndarray:
    e = np.exp2(np.linspace(-12, 6, 20001))
    c = camera(e)
    first = np.searchsorted(c, codes)  # the exposure at which the camera first reaches each code
    return np.log2(e[np.clip(first, 0, len(e) - 1)])


def test_fit_response_recovers_a_known_curve_from_two_exposures():
    rng = np.random.default_rng(0)
    log2e = rng.uniform(-9, 2, (40000, 1)).repeat(3, 1)
    noise = lambda: rng.normal(0, 0.5 / 255, log2e.shape)
    a = np.clip(camera(np.exp2(log2e)) + noise(), 0, 1)
    b = np.clip(camera(np.exp2(log2e + 3)) + noise(), 0, 1)
    r = fit_response(a, b, np.full(len(a), 3.0))
    codes = np.linspace(0.06, 0.9, 30)
    err = np.abs(np.interp(codes, r.codes, r.g[1]) - truth_g(codes))
    assert err.max() < 0.15, err.max()  # a sigmoid start is off by up to 2.5 stops here
    assert abs(np.interp(0.5, r.codes, r.g[0])) < 1e-6  # T(0) = 0.5
    assert np.all(np.diff(r.g, axis=1) > 0)


def test_matched_codes_follow_the_flow_and_skip_pairs_of_one_exposure():
    rng = np.random.default_rng(1)
    T, H, W, shift = 3, 40, 48, 3
    scene = np.exp2(rng.uniform(-6, 1, (H, W + 3 * shift, 1))).repeat(3, 2)
    dt = np.array([0.0, 2.0, 2.0])
    frames = np.stack([camera(scene[:, t * shift:t * shift + W] * 2 ** dt[t]) for t in range(T)]).astype(np.float32)
    fw = np.zeros((T - 1, H // 2, W // 2, 2), np.float32)
    fw[..., 0] = -shift / 2  # pixels of the half-size working grid: frame t+1 shows the scene 3 px further left
    fl = FlowArrays(fw=fw, fw_ok=np.ones(fw.shape[:3], bool), vis=np.ones(fw.shape[:3], bool))
    a, b, dz = matched_codes(frames, dt, fl)
    assert np.all(dz == 2.0) and len(a) > 300  # only the pair 0-1 differs in exposure
    g = fit_response(a, b, dz)
    assert g is not None
    codes = np.linspace(0.1, 0.6, 12)
    assert np.abs(np.interp(codes, g.codes, g.g[1]) - truth_g(codes)).max() < 0.3


def test_tone_mapper_starts_on_the_measured_response():
    rng = np.random.default_rng(2)
    log2e = rng.uniform(-9, 2, (20000, 1)).repeat(3, 1)
    r = fit_response(camera(np.exp2(log2e)), camera(np.exp2(log2e + 2)), np.full(len(log2e), 2.0))
    torch.manual_seed(0)
    tone = ToneMapper(lut=1024)
    fit_init_curve(tone, response=r)
    z = torch.from_numpy(truth_g(np.linspace(0.1, 0.9, 9))).float()
    c = tone.curve(z)[:, 1].numpy()
    assert np.abs(c - np.linspace(0.1, 0.9, 9)).max() < 0.03


def test_no_usable_match_gives_no_response_and_twelve_stops_stay_finite():
    rng = np.random.default_rng(3)
    black = np.zeros((5000, 3))
    assert fit_response(black, black, np.full(5000, 3.0)) is None  # nothing between the ends: the sigmoid start
    log2e = rng.uniform(-14, 2, (40000, 1)).repeat(3, 1)
    a, b = camera(np.exp2(log2e)), camera(np.exp2(log2e + 12))  # 12 stops: few codes seen in both
    r = fit_response(a, b, np.full(len(a), 12.0))
    assert r is not None and np.all(np.isfinite(r.g)) and np.all(np.diff(r.g, axis=1) > 0)
    z = np.linspace(-40, 40, 81)[:, None].repeat(3, 1)
    assert np.all(np.isfinite(r.logits(z))) and np.all(np.diff(r.logits(z), axis=0) >= 0)
