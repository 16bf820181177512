"""Figures of layercam.bench.viz: built from arrays without pyplot, shapes checked, CRF alignment exact."""

from __future__ import annotations

import numpy as np
import pytest

from layercam import synth

from layercam.bench import viz


def test_align_crf_recovers_a_known_shift_per_channel():
    z = np.linspace(-12, 12, 241)
    shift = np.array([-2.5, -3.0, -1.75])
    learned = np.stack([synth.crf_apply(np.exp2(z + s), "srgb") for s in shift], 1)
    truth, found = viz.align_crf(z, learned, lambda x: synth.crf_apply(x, "srgb"))
    assert np.allclose(found, shift, atol=0.051)
    assert truth.shape == (241, 3) and np.abs(truth - learned).max() < 0.02


def test_align_crf_per_channel_truth():
    z = np.linspace(-10, 10, 101)
    learned = synth.crf_apply(np.exp2(z + 1.0)[:, None].repeat(3, 1), "mixed")
    _, found = viz.align_crf(z, learned, lambda x: synth.crf_apply(x, "mixed"))
    assert np.allclose(found, 1.0, atol=0.051)
    with pytest.raises(ValueError):
        viz.align_crf(z, learned[:, :2], lambda x: x)


def test_figures_are_pyplot_free_and_render(tmp_path):
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(0)
    T, H, W = 5, 12, 16
    frames = rng.random((T, H, W, 3)).astype(np.float32)
    alpha = rng.random((T, H, W)).astype(np.float32)
    before = plt.get_fignums()
    figs = {
        "atlas": viz.atlas_figure([frames[0][:12, :12]] * 2, [alpha[0][:8, :8]] * 2, [frames[1][:12, :12]] * 2),
        "atlas_alone": viz.atlas_figure([frames[0]]),
        "alpha": viz.alpha_figure(alpha, frames, truth=alpha > 0.5),
        "no_alpha": viz.alpha_figure(None),
        "uv": viz.uv_checker_figure([frames, frames], max_frames=3),
        "crf": viz.crf_figure(np.linspace(-4, 4, 9), rng.random((9, 3)), rng.random((9, 3)),
                              np.zeros(3), data_range=(-1, 1)),
        "exposures": viz.exposures_figure(np.array([0, 2.1, 0, 2.1]),
                                          given=np.array([0, 3, 0, 3.0]),
                                          truth=np.array([0, 2, 0, 2.0])),
        "kernels": viz.kernels_figure(rng.normal(size=(3, 9, 2)), np.full((3, 9), 1 / 9),
                                      np.array([[1, 2], [3, 4], [5, 6]]), frames[0],
                                      max_offset=2.0),
        "no_kernels": viz.kernels_figure(None, None),
        "sweep": viz.sweep_figure(frames[:3], [-2, 0, 2]),
    }
    panels = {k: len([a for a in f.axes if a.get_label() != "<colorbar>"]) for k, f in figs.items()}
    assert panels["atlas"] == 6 and panels["atlas_alone"] == 1
    assert panels["alpha"] == 3 * T and panels["uv"] == 2 * 3 and panels["crf"] == 3 and panels["sweep"] == 3
    assert panels["kernels"] == 1 + 3
    for name in ("atlas_alone", "no_alpha", "no_kernels"):  # the notebook's test draws the others
        figs[name].savefig(tmp_path / f"{name}.png", dpi=40)
        assert (tmp_path / f"{name}.png").stat().st_size > 500, name
    assert plt.get_fignums() == before  # nothing left open in pyplot's global state


def test_figures_check_their_shapes():
    with pytest.raises(ValueError):
        viz.atlas_figure([])
    with pytest.raises(ValueError):
        viz.atlas_figure([np.zeros((4, 4, 3))], [np.zeros((4, 4))] * 2)
    with pytest.raises(ValueError):
        viz.alpha_figure(np.zeros((4, 4)))
    with pytest.raises(ValueError):
        viz.alpha_figure(np.zeros((2, 4, 4)), truth=np.zeros((3, 4, 4)))
    with pytest.raises(ValueError):
        viz.kernels_figure(np.zeros((2, 9, 2)), np.zeros((2, 8)))
    with pytest.raises(ValueError):
        viz.sweep_figure(np.zeros((2, 4, 4, 3)), [0.0])
