"""``layercam.engine.estimate``: what a training step keeps is measured on the model, not modelled."""

from __future__ import annotations

import numpy as np
import pytest

from layercam.core.presets import load_config
from layercam.engine.estimate import bound, estimate
from layercam.engine.model_cost import identity_meta, kept_for_backward


def test_kept_for_backward_follows_the_networks_width():
    fast = bound(load_config("fast", ["model.layers=2"]), "hdr-video", 8, (64, 64))
    paper = bound(load_config("paper", ["model.layers=2"]), "hdr-video", 8, (64, 64))
    one = bound(load_config("paper", ["model.layers=1"]), "hdr-video", 8, (64, 64))
    (f0, f), (p0, p), (_, p1) = kept_for_backward(fast), kept_for_backward(paper), kept_for_backward(one)
    assert f > 0 and f0 >= 0
    assert p > 3 * f          # 4x512 MLPs keep more per sample than 2x64 ones over grids
    assert 1.5 < p / p1 < 2.5  # two layers, about twice one's


def test_the_paper_preset_is_not_refused_for_a_small_clip():
    """Its 30,000-sample batches of 4x512 MLPs: a step peaks at about 2.2 GB (measured on a 144x256
    clip, two layers), which the estimate must not call 24 GB."""
    est = estimate({"frames": 48, "width": 256, "height": 144}, load_config("paper"))
    assert est["assumed"]["layers"] == 2
    assert 1.5e9 < est["memory"] < 4e9


def test_a_huge_batch_is_still_refused_on_its_activations(tmp_path):
    from layercam.core.errors import LayercamError
    from layercam.engine.estimate import check

    est = estimate({"frames": 48, "width": 854, "height": 480},
                   load_config("fast", ["train.batch=1000000000", "train.passes_per_frame=0"]))
    with pytest.raises(LayercamError, match="train.batch"):
        check(est, tmp_path)


def test_the_estimate_counts_the_atlas_the_camera_pans_over():
    """After the analysis the model is counted with the atlas grid the bootstrap's chained
    homographies size (a pan widens it past the still camera's); before it, at the widest."""
    from types import SimpleNamespace

    import torch

    from layercam.core.geometry import atlas_mappings, chain_homographies, middle_frame
    from layercam.engine.checkpoint import build_model
    from layercam.pipelines.windows.plan import extent
    from layercam.scene.layered import derived_sizes

    T, hw = 8, (64, 64)
    homs = np.tile(np.eye(3), (T - 1, 1, 1))
    homs[:, 0, 2] = 12.0  # the view moves 12 px a frame
    px = extent(SimpleNamespace(T=T, H=64, W=64), SimpleNamespace(homs=homs, fw=None, grid=hw), [(0, T)])
    cfg = load_config("fast", [])
    r = bound(cfg, "hdr-video", T, hw)
    maps = atlas_mappings(*hw, chain_homographies(homs, middle_frame(T)))
    h0 = np.stack([maps] * int(r.settings.model.layers))
    # as the run's model derives them
    meta = {**identity_meta(r, T, hw), "h0": h0, "sizes": derived_sizes(h0, hw, fine=False)}
    with torch.device("meta"):
        built = sum(p.numel() for p in build_model(r, meta).parameters())
    info = {"frames": T, "width": 64, "height": 64}
    counted = lambda **k: sum(estimate(info, cfg, **k)["params"].values())  # noqa: E731
    with torch.device("meta"):
        still = sum(p.numel() for p in build_model(r, identity_meta(r, T, hw)).parameters())
    assert counted(extent=px) == built > still and counted() >= built
