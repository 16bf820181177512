"""``layercam bench --suite real`` end to end on one NTIRE case with a few training steps (needs the
shared captures), resumability, and its one-line errors."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from layercam.cli import main


@pytest.mark.data
def test_real_suite_smoke_on_one_ntire_case(tmp_path, shared_data, capsys):
    out = tmp_path / "real"
    args = ["bench", "--suite", "real", "--quick", "--cases", "ntire-000000", "--presets", "fast",
            "--out", str(out), "--data", str(shared_data)]
    assert main(args) == 0
    rows = list(csv.DictReader(open(out / "real_suite.csv")))
    assert [(r["method"], r["preset"]) for r in rows] == [("debevec", ""), ("robertson", ""), ("layercam", "fast")]
    for r in rows:
        assert (np.isfinite(float(r["psnr_mu"])) and np.isfinite(float(r["psnr_t"]))
                and float(r["wall_s"]) > 0 and float(r["peak_mem_mb"]) > 0)
        assert r["truth"] == "truth" and r["channels"] == "RB"
    lc = json.loads((out / "cases/ntire-000000/layercam-fast/result.json").read_text())["rows"][0]
    assert lc["analysis"]["choice"] and "fuse-stack" in lc["command"] and "--reference 1" in lc["command"]
    assert (out / "cases/ntire-000000/figure.png").stat().st_size > 5000
    assert "| ntire-000000 | layercam | `fast` |" in (out / "real_suite.md").read_text()
    # resumable: a second run skips every finished job
    stamp = (out / "cases/ntire-000000/layercam-fast/result.json").stat().st_mtime
    capsys.readouterr()
    assert main(args) == 0
    assert capsys.readouterr().out.count("done before, skipped") == 3
    assert (out / "cases/ntire-000000/layercam-fast/result.json").stat().st_mtime == stamp


@pytest.mark.data
def test_real_suite_shaken_still_scores_against_its_own_sharp_frames(tmp_path, shared_data):
    """``gopro-shake``: a real sharp frame shaken along known paths, rendered once, scored (input,
    the classical baselines, layercam) against the sharp frames it was made from."""
    out = tmp_path / "real"
    args = ["bench", "--suite", "real", "--quick", "--cases", "gopro-shake", "--presets", "fast",
            "--out", str(out), "--data", str(shared_data)]
    assert main(args) == 0
    rows = {r["method"]: r for r in csv.DictReader(open(out / "real_suite.csv"))}
    assert set(rows) == {"input", "unsharp", "lucky", "layercam"}
    assert float(rows["input"]["gain_db"]) == 0.0 and 20 < float(rows["input"]["psnr"]) < 60
    assert np.isfinite(float(rows["layercam"]["psnr"])) and rows["layercam"]["truth"] == "truth"
    z = np.load(out / "cases/gopro-shake/inputs/shake.npz")
    assert (z["sharp"].shape == (3, 48, 64, 3)
            and len(list((out / "cases/gopro-shake/inputs/frames").glob("*.png"))) == 3)


def test_real_suite_unknown_case_and_missing_data_are_one_line_errors(tmp_path, capsys):
    assert main(["bench", "--suite", "real", "--cases", "nope", "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert "unknown real-suite case 'nope'" in err and len(err.strip().splitlines()) == 1
    assert main(["bench", "--suite", "real", "--out", str(tmp_path / "r"), "--data", str(tmp_path / "none")]) == 2
    assert "shared captures not found" in capsys.readouterr().err
