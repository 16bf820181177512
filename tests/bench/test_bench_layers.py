"""``layercam bench --table layers`` (layercam.bench.layers): alpha against true masks on real clips."""

from __future__ import annotations

import json

import numpy as np
import pytest

from layercam.bench import layers as bench_layers
from layercam.core.errors import LayercamError
from layercam.bench.viz import error_overlay


def test_mask_ious_and_error_overlay():
    truth = np.zeros((2, 8, 8), np.float32)
    truth[:, 2:6, 2:6] = 1
    pred = truth.copy()
    pred[1, 2:6, 2:4] = 0  # half of the object missed in frame 1
    pred[1, 0, 0] = 1  # and one false positive
    ious = bench_layers.mask_ious(pred, truth)
    assert ious[0] == 1.0 and abs(ious[1] - 8 / 17) < 1e-9
    img = error_overlay(np.full((8, 8, 3), 0.5, np.float32), pred[1], truth[1])
    assert img[0, 0, 0] > 0.6 and img[0, 0, 1] < 0.3  # false positive: red
    assert img[3, 2, 2] > 0.6 and img[3, 2, 0] < 0.3  # missed: blue
    assert img[3, 5, 1] > 0.6 and img[3, 5, 0] < 0.3  # found: green
    assert np.allclose(img[7, 7], 0.45 * 0.5)  # agreed background: the frame darkened


def test_find_clips_and_table(tmp_path):
    with pytest.raises(LayercamError, match="no layers_davis"):
        bench_layers.find_clips(tmp_path)
    for n in ("a", "b", "dog"):
        (tmp_path / f"layers_davis_{n}" / "frames").mkdir(parents=True)
        (tmp_path / f"layers_davis_{n}" / "masks_gt").mkdir()
    assert list(bench_layers.find_clips(tmp_path)) == ["a", "b", "dog"]
    assert list(bench_layers.find_clips(tmp_path, ["b"])) == ["b"]
    # the splits: DAVIS 2016's validation sequences are judged on, every other clip is training
    assert list(bench_layers.find_clips(tmp_path, split="validation")) == ["dog"]
    assert list(bench_layers.find_clips(tmp_path, split="training")) == ["a", "b"]
    with pytest.raises(LayercamError, match="unknown split"):
        bench_layers.find_clips(tmp_path, split="test")
    with pytest.raises(LayercamError, match="unknown clip 'c'"):
        bench_layers.find_clips(tmp_path, ["c"])
    row = {"clip": "a", "variant": "motion", "preset": "fast", "frames": 3, "size": "8x8",
           "layers": 2, "iou": 0.5, "iou_min": 0.25, "inside": 0.9, "bootstrap_iou": 0.4,
           "found": True, "psnr": 30.0, "wall_s": 12.0,
           "iou_source": 0.45, "iou_min_source": 0.2, "inside_source": 0.85, "source_size": "16x16"}
    rows = [row, {**row, "clip": "b", "iou": 0.7, "inside": 0.7, "found": False},
            {**row, "variant": "masks", "bootstrap_iou": None, "found": None, "iou": 0.9},
            {**row, "clip": "dog", "iou": 0.8, "bootstrap_iou": 0.75}]
    bench_layers.write_layers_table(tmp_path, rows)
    text = (tmp_path / "layers.md").read_text()
    md = text.splitlines()
    assert ("| a | fast | 3 | 8x8 | none (motion) | 2 | 0.500 | 0.250 | 0.900 | 0.450 / 0.850 "
            "(16x16) | 0.400 | yes | 30.00 | 12 |" in md)
    assert ("| b | fast | 3 | 8x8 | none (motion) | 2 | 0.700 | 0.250 | 0.700 | 0.450 / 0.850 "
            "(16x16) | 0.400 | no | 30.00 | 12 |" in md)
    # per split, never mixed: the mean over the split's clips with its bootstrap masks' mean, the
    # least share inside, the worst clip, per preset and variant; the validation split first
    assert text.index("## The validation split") < text.index("## The training split")
    assert text.index("| dog | fast |") < text.index("## The training split") < text.index("| a | fast |")
    assert "| fast | none (motion) | 2 | 0.600 | 0.400 | 0.800 | 0.700 | a 0.500 | 0.450 / 0.850 / 0.450 |" in md
    assert "| fast | none (motion) | 1 | 0.800 | 0.750 | 0.900 | 0.900 | dog 0.800 | 0.450 / 0.850 / 0.450 |" in md
    assert "| fast | given | 1 | 0.900 |  | 0.900 | 0.900 | a 0.900 | 0.450 / 0.850 / 0.450 |" in md
    summary = json.loads((tmp_path / "layers.json").read_text())["summary"]
    assert [(s["split"], s["clips"]) for s in summary] == [("validation", 1), ("training", 2), ("training", 1)]


def test_inside_share_is_the_object_under_alpha():
    truth = np.zeros((2, 4, 4), bool)
    truth[:, :2, :2] = True
    pred = np.zeros((2, 4, 4), np.float32)
    pred[0, :2, :2] = 1.0
    pred[1] = 0.4  # under 0.5: not inside
    assert bench_layers.inside_share(pred, truth) == 0.5
    assert bench_layers.inside_share(pred, np.zeros_like(truth)) == 1.0


def test_source_scores_are_at_the_masks_own_size(tmp_path):
    """Scored as DAVIS scores: a matte at a third of the size, upsampled, against the masks at theirs;
    a line one source pixel wide is object there, though no pixel of the matte's size is mostly line."""
    import cv2

    from layercam.io import Clip

    src = np.zeros((24, 24), np.uint8)
    src[3:15, 3:15] = 255  # cells 1-4 of the 8x8 grid, whole
    src[18, :] = 255  # a line: a third of row 6's cells
    (tmp_path / "m").mkdir()
    assert cv2.imwrite(str(tmp_path / "m" / "0.png"), src)
    clip = Clip(frames=np.zeros((1, 8, 8, 3), np.float32), source="test", names=["0"], meta={})
    alpha = np.zeros((1, 8, 8), np.float32)
    alpha[0, 1:5, 1:5] = 1.0
    sc = bench_layers.source_scores(alpha, tmp_path / "m", clip)
    assert sc["source_size"] == "24x24"
    assert abs(sc["inside_source"] - 144 / 168) < 0.03  # the block inside (to its upsampled edge), the line not
    assert 0.8 < sc["iou_source"] < 0.9 and sc["iou_min_source"] == sc["iou_source"]


@pytest.mark.data
def test_layer_job_on_a_real_clip_and_resume(shared_data, tmp_path):
    folder = shared_data / "layers_davis_cows"
    if not folder.is_dir():
        pytest.skip(f"{folder} is absent")
    job = {"clip": "cows", "folder": str(folder), "variant": "motion", "preset": "fast",
           "resize": "0.1", "max_frames": 4, "layers": "2",
           "overrides": ["train.steps=20", "train.bootstrap_steps=5", "train.batch=1024"],
           "run": str(tmp_path / "runs" / "cows-motion"),
           "figure": str(tmp_path / "cows-motion.png")}
    row = bench_layers.run_layer_job(job)
    assert row["layers"] == 2 and row["frames"] == 4 and row["size"] == "85x48"
    assert (len(row["per_frame_iou"]) == 4 and 0.0 <= row["iou"] <= 1.0
            and 0.0 <= row["bootstrap_iou"] <= 1.0 and 0.0 <= row["inside"] <= 1.0)
    assert row["found"] in (True, False) and row["verdict"]
    assert row["source_size"] == "854x480" and 0.0 <= row["iou_source"] <= 1.0 and 0.0 <= row["inside_source"] <= 1.0
    assert np.isfinite(row["psnr"]) and row["psnr"] > 10
    assert (tmp_path / "cows-motion.png").stat().st_size > 10_000
    # a finished job's result is re-used, not re-run (no subprocess is started for it)
    (tmp_path / "results").mkdir()
    (tmp_path / "results" / "cows-motion-fast.json").write_text(json.dumps(row))
    rows = bench_layers.run_layers_table(tmp_path, shared_data, ["cows"], ("motion",), ("fast",), progress=False)
    assert rows == [row] and "| cows | fast | 4 | 85x48 |" in (tmp_path / "layers.md").read_text()
