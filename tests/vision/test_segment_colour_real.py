"""The colour cut on a real capture of ../shared/data: motorbike, a rider on a road with a flower
pot near the lens that moves against the far road by parallax (DAVIS 2016's training split)."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.mark.data
def test_real_colour_cut_keeps_the_rider_not_the_larger_pot(shared_data):
    """At the layers bench's setting (24 frames at 282x158) the colour cut, whose colour model also
    reaches the pot, keeps the part that holds the mask it grew from (the rider), not the largest
    part (the pot: the finder's masks scored 0.35 when it kept the largest)."""
    from layercam.bench.finder import clip_flows
    from layercam.bench.layers import inside_share, mask_ious
    from layercam.core.presets import load_config
    from layercam.io import load_clip
    from layercam.io.masks import load_masks
    from layercam.vision.segment import find_foreground

    d = shared_data / "layers_davis_motorbike"
    if not d.is_dir():
        pytest.skip(f"{d} is absent")
    clip = load_clip(d / "frames", max_frames=24, resize="0.33")
    truth = load_masks(d / "masks_gt", clip)
    cfg = load_config("fast")
    masks, _ = find_foreground(clip.frames, clip_flows(clip, cfg.flow), cfg.segment)
    assert np.mean(mask_ious(masks, truth)) > 0.7
    assert inside_share(masks, truth) > 0.9
