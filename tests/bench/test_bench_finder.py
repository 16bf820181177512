"""``layercam bench --table finder`` (layercam.bench.finder): the finder's steps, each left out, on real clips."""

from __future__ import annotations

import json

import numpy as np
import pytest

from layercam.bench import finder
from layercam.vision.segment import STEPS


def test_step_sets_leave_each_step_out():
    sets = finder.step_sets()
    assert sets["all"] == STEPS and sets["motion masks alone"] == ()
    assert sets["without grabcut"] == ("travel", "background", "colour", "texture", "contrast", "guided")
    # the colour cut and the texture test read the clean plate: without it, neither
    assert sets["without background (and colour, texture)"] == ("travel", "grabcut", "contrast", "guided")
    assert len(sets) == len(STEPS) + 2


def test_summary_is_the_sets_mean_and_worst_clip():
    def row(clip, iou):
        return {"clip": clip, "preset": "fast", "frames": 3, "size": "8x8", "flow_s": 1.0,
                "sets": {k: {"iou": iou, "iou_min": iou / 2, "inside": 0.9, "seconds": 0.1}
                         for k in finder.step_sets()}}

    rows = [row("a", 0.5), row("b", 0.8)]
    summary = finder.summarise(rows)
    top = summary[0]
    assert top["steps"] == "all" and top["mean"] == 0.65 and top["worst_clip"] == "a" and top["worst"] == 0.5
    md = finder.finder_markdown(rows, summary, "layercam bench --table finder")
    assert "| `fast` | all | 2 | 0.650 | a 0.500 | 0.900 |" in md
    assert "| a | `fast` | 0.500 (0.25) |" in md


def test_finder_table_on_a_real_clip_and_resume(shared_data, tmp_path):
    if not (shared_data / "layers_davis_dog").is_dir():
        pytest.skip(f"{shared_data / 'layers_davis_dog'} is absent")
    rows = finder.run_finder_table(tmp_path, shared_data, ["dog"], ("fast",), resize="0.2",
                                   max_frames=8, progress=False)
    (r,) = rows
    assert r["frames"] == 8 and set(r["sets"]) == set(finder.step_sets())
    assert all(0.0 <= v["iou_min"] <= v["iou"] <= 1.0 and 0.0 <= v["inside"] <= 1.0 for v in r["sets"].values())
    assert r["sets"]["all"]["iou"] > 0.3  # the dog is found
    saved = json.loads((tmp_path / "finder.json").read_text())
    assert saved["rows"] == rows and saved["summary"][0]["worst_clip"] == "dog"
    # a finished clip is read back, not run again
    res = tmp_path / "results" / "finder-dog-fast.json"
    res.write_text(json.dumps({**r, "flow_s": -1.0}))
    assert finder.run_finder_table(tmp_path, shared_data, ["dog"], ("fast",), resize="0.2",
                                   max_frames=8, progress=False)[0]["flow_s"] == -1.0
    assert np.isfinite(r["flow_s"])
