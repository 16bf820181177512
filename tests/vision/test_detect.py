"""The optional detector (layercam.vision.segment.detect): a local Mask R-CNN weights file's instances replace the
motion masks where they lie in them. No weights are downloaded; the tests build a torchvision
Mask R-CNN with random weights and save it, so they check the file handling and the plumbing,
not what trained weights find (none are on these machines)."""

from __future__ import annotations

import numpy as np
import pytest

from layercam.vision.segment import detect

from layercam.vision import segment
from layercam.core.presets import load_config
from layercam.core.errors import LayercamError


def test_pick_instances_takes_the_whole_object_where_the_motion_masks_hold_part_of_it():
    """The motion mask holds the left half of a square (a trunk hid the rest): the detector's
    square lies 0.5 in it and replaces it; an instance elsewhere (a parked car) is left out; a
    frame whose instances all lie outside keeps its motion mask, as does a frame without any."""
    motion = np.zeros((3, 40, 40), np.float32)
    motion[:, 10:20, 10:15] = 1  # the left half of the object
    square = np.zeros((40, 40), bool)
    square[10:20, 10:20] = True
    parked = np.zeros((40, 40), bool)
    parked[30:38, 25:38] = True
    found = [
        {"masks": np.stack([square, parked]), "scores": np.array([0.9, 0.9]), "labels": np.array([18, 3])},
        {"masks": parked[None], "scores": np.array([0.9]), "labels": np.array([3])},
        {"masks": np.zeros((0, 40, 40), bool), "scores": np.zeros(0), "labels": np.zeros(0, int)},
    ]
    out, info = detect.pick_instances(found, motion, overlap=0.3)
    assert out.dtype == np.float32 and out.shape == motion.shape
    assert (out[0] > 0.5).tolist() == square.tolist()
    assert (out[1] == motion[1]).all() and (out[2] == motion[2]).all()
    assert info == {"detector_frames": 1, "detector_instances": 1}
    # at overlap 0.6 the half-covered square is not the object's either
    assert detect.pick_instances(found, motion, overlap=0.6)[1]["detector_frames"] == 0


def test_a_missing_or_foreign_detector_file_is_one_clear_error(tmp_path):
    import torch

    with pytest.raises(LayercamError, match="segment.detector: no such file"):
        load_config("fast", [f"segment.detector={tmp_path / 'nope.pth'}"])
    other = tmp_path / "other.pth"
    torch.save({"conv.weight": torch.zeros(3, 3)}, other)
    with pytest.raises(LayercamError, match="is not a torchvision Mask R-CNN state dict"):
        detect.load_detector(str(other))
    junk = tmp_path / "junk.pth"
    junk.write_bytes(b"not a torch file")
    with pytest.raises(LayercamError, match="cannot read"):
        detect.load_detector(str(junk))


@pytest.fixture(scope="module")
def random_maskrcnn(tmp_path_factory):
    """A torchvision Mask R-CNN (v1, COCO's 91 classes) with random weights, saved as a user's
    weights file would be (180 MB)."""
    import torch
    from torchvision.models.detection import maskrcnn_resnet50_fpn

    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("detector") / "maskrcnn.pth"
    torch.save(maskrcnn_resnet50_fpn(weights=None, weights_backbone=None, num_classes=91).state_dict(), path)
    return str(path)


def test_the_bootstrap_runs_a_detector_file_and_says_what_it_took(random_maskrcnn):
    """Through ``foreground_bootstrap``: the file loads, each frame's instances come back at the
    frame's size above the score, and the masks are the motion masks except in the frames the
    detector's instances replaced, which the info counts."""
    from layercam.vision import flow
    from test_segment import _square_clip

    frames, _, _ = _square_clip(T=4, size=48, side=14)
    fw, bw = flow.compute_flow(frames, "dis_fast", progress=False)
    fl = {"fw": fw, "bw": bw, "fw_ok": flow.flow_consistency(fw, bw), "homs": flow.global_homographies(fw)}
    cfg = load_config("fast", ["segment.detector_size=96", "segment.detector_score=0.3"]).segment
    found = detect.detect_instances(frames, random_maskrcnn, score=0.3, size=96)
    assert len(found) == 4
    for d in found:
        assert d["masks"].shape[1:] == (48, 48) and d["masks"].dtype == bool
        assert (d["scores"] >= 0.3).all() and len(d["scores"]) == len(d["masks"]) == len(d["labels"])
    motion = segment.foreground_bootstrap(frames, fl, cfg=cfg)
    cfg.detector = random_maskrcnn
    both = segment.foreground_bootstrap(frames, fl, cfg=cfg)
    assert both["computed"] and both["masks"].shape == motion["masks"].shape
    expected, info = detect.pick_instances(found, motion["masks"], cfg.detector_overlap)
    assert {k: both["info"][k] for k in info} == info
    assert info["detector_frames"] > 0  # random weights, seed 0: 2 of the 4 frames
    assert (both["masks"] == expected).all()
    kept = [t for t in range(4) if (both["masks"][t] == motion["masks"][t]).all()]
    assert len(kept) >= 4 - info["detector_frames"]
