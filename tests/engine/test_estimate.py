"""``layercam.engine.estimate``: what a training step keeps is measured on the model, not modelled."""

from __future__ import annotations

import pytest

from layercam.core.presets import load_config
from layercam.engine.estimate import _resolved, estimate, kept_for_backward


def test_kept_for_backward_follows_the_networks_width():
    fast = _resolved(load_config("fast", ["model.layers=2"]), "hdr-video", 8, (64, 64))
    paper = _resolved(load_config("paper", ["model.layers=2"]), "hdr-video", 8, (64, 64))
    one = _resolved(load_config("paper", ["model.layers=1"]), "hdr-video", 8, (64, 64))
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

    est = estimate({"frames": 48, "width": 854, "height": 480}, load_config("fast", ["train.batch=1000000000", "train.passes_per_frame=0"]))
    with pytest.raises(LayercamError, match="train.batch"):
        check(est, tmp_path)
