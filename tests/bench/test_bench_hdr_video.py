"""``layercam bench --table hdr-video`` (layercam.bench.hdr_video): hdr.mp4's cost and round trip."""

from __future__ import annotations

import json

import numpy as np
import pytest

from layercam.bench.hdr_video import table
from layercam.cli import main


def test_table_takes_medians_and_hdr_mp4s_share():
    rows = [{"format": "none", "export_s": 10.0},
            {"format": "pq", "export_s": 12.0, "hdr_video": {"seconds": 2.0},
             "round_trip": {"kbit_s": 200.0, "median_lum_error": 0.01}},
            {"format": "none", "export_s": 14.0},
            {"format": "pq", "export_s": 14.0, "hdr_video": {"seconds": 4.0},
             "round_trip": {"kbit_s": 210.0, "median_lum_error": 0.02}}]
    md = table(rows, ["none", "pq"], 2).splitlines()
    assert md[2] == "| none | 12.0 | 0.0 |  |  |  |  |"
    assert md[3] == "| pq | 13.0 | 3.0 | +30.0% | 210.0 | 0.02 |  |"  # medians; the last round trip
    assert md[-1] == "export without hdr.mp4 (none): 12.0 s (median of 2)"


@pytest.mark.timeout(600)  # an hdr-video process and a render
def test_quick_hdr_video_table_round_trips_and_draws(tmp_path, capsys):
    """--quick on a synthetic alternating-exposure clip: a trained run exported as PQ, hdr.mp4
    decoded back against the EXRs, and the figure (preview | PQ for SDR | HLG)."""
    out = tmp_path / "hdr"
    assert main(["bench", "--table", "hdr-video", "--quick", "--variants", "pq", "--out", str(out), "--quiet"]) == 0
    rows = json.loads((out / "hdr_video.json").read_text())
    assert [r["format"] for r in rows] == ["pq"] and rows[0]["hdr_video"]["format"] == "pq"
    assert rows[0]["export_s"] > 0 and 0 < rows[0]["hdr_video"]["seconds"] < rows[0]["export_s"]
    rt = rows[0]["round_trip"]
    assert 0 < rt["well_exposed_share"] <= 1 and 0 <= rt["median_lum_error"] < 0.5 and rt["kbit_s"] > 0
    md = (out / "hdr_video.md").read_text().splitlines()
    assert len(md) == 3 and md[2].startswith("| pq |") and str(rt["kbit_s"]) in md[2]
    import cv2

    img = cv2.imread(str(out / "hdr_video.png"))
    assert img.shape[1] == 3 * 96 + 8 and img.std() > 5  # three panels of the 96-px-wide clip
    assert (out / "run" / "render" / "hdr_hlg.mp4").is_file() and not capsys.readouterr().out


def test_hdr_video_bad_format_and_missing_clip_are_one_line_errors(tmp_path, capsys):
    assert main(["bench", "--table", "hdr-video", "--variants", "pq,dolby", "--out",
                 str(tmp_path / "h"), "--data", str(tmp_path)]) == 2
    assert "dolby" in capsys.readouterr().err
    assert main(["bench", "--table", "hdr-video", "--out", str(tmp_path / "h"), "--data", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err
    assert "missing shared capture" in err and len(err.strip().splitlines()) == 1
