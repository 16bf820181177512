"""``layercam bench --table joins`` (layercam.bench.joins): two windows against one model."""

from __future__ import annotations

import json

import numpy as np
import pytest

from layercam.bench.joins import centred, forth_and_back, pair_flicker, per_frame_psnr_mu, two_windows
from layercam.cli import main
from layercam.pipelines.windows.plan import overlap_for, split


def test_two_windows_cut_any_length_in_two():
    assert two_windows(96) == 57 and split(96, 57, 2) == [(0, 57), (39, 96)]
    for T in range(12, 400):
        n = two_windows(T)
        w = split(T, n, 2)
        assert len(w) == 2 and w[0][0] == 0 and w[1][1] == T and 0 < w[0][1] - w[1][0] <= overlap_for(n, 2), T
        assert len(split(T, n - 1, 2)) == 3, T  # the shortest such length


def test_forth_and_back_and_per_frame_psnr():
    assert forth_and_back(4, 9) == [0, 1, 2, 3, 2, 1, 0, 1, 2]
    assert forth_and_back(4, 9, 2) == [2, 1, 0, 1, 2, 3, 2, 1, 0]
    idx = centred(74, 96)  # the Basler clip: each of two windows holds 46 distinct frames
    assert idx[:3] == [11, 10, 9] and idx[-3:] == [64, 63, 62] and all(abs(a - b) == 1 for a, b in zip(idx, idx[1:]))
    assert len(set(idx[:57])) == len(set(idx[39:])) == 46 and centred(5, 4) == [0, 1, 2, 3]
    gt = np.random.default_rng(0).random((3, 8, 8, 3)).astype(np.float32) + 0.1
    pred = gt * 2.0  # one scale: aligned away
    pred[2] += 0.05  # frame 2 off
    ps = per_frame_psnr_mu(pred, gt)
    assert ps[0] > 60 and ps[1] > 60 and ps[2] < 45


def test_pair_flicker_on_static_pixels():
    hdr = np.full((3, 16, 16, 3), 0.3, np.float32)
    hdr[2] *= 1.5  # the pair (1, 2) changes
    hom = np.tile(np.eye(3), (2, 1, 1))
    static = np.ones((2, 16, 16), bool)
    static[0] = False  # no static pixel in pair (0, 1)
    fl = pair_flicker(hdr, hom, static)
    assert np.isnan(fl[0]) and fl[1] > 1


def test_unknown_joins_case_and_missing_data_are_one_line_errors(tmp_path, capsys):
    assert main(["bench", "--table", "joins", "--cases", "nope", "--out", str(tmp_path / "j"),
                 "--data", str(tmp_path)]) == 2
    assert "unknown case 'nope'" in capsys.readouterr().err
    assert main(["bench", "--table", "joins", "--out", str(tmp_path / "j"), "--data", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err
    assert "shared captures not found" in err and len(err.strip().splitlines()) == 1


@pytest.mark.data
@pytest.mark.timeout(900)  # two hdr-video runs (one model, two windows) of 24 frames
def test_quick_joins_on_the_composite(shared_data, tmp_path):
    """--quick: the composite (a real person over a real radiance map, truth per frame) 24 frames
    long at 48x64, one model and two windows of 14 frames; a second call reuses both runs."""
    out = tmp_path / "joins"
    argv = ["bench", "--table", "joins", "--quick", "--cases", "composite", "--out", str(out),
            "--data", str(shared_data), "--quiet"]
    assert main(argv) == 0
    rep = json.loads((out / "joins.json").read_text())
    assert rep["window"] == "14" and rep["preset"] == "fast"
    r = rep["results"][0]
    assert r["case"] == "composite" and r["overlap"] == [10, 14] and r["join_pairs"] == [9, 10, 11, 12, 13]
    assert len(r["psnr_single"]) == len(r["psnr_windows"]) == 24 and np.load(out / "composite"
        / "truth.npy").shape == (24, 48, 64, 3)
    assert np.isfinite(r["psnr_single_mean"]) and np.isfinite(r["psnr_windows_mean"]) and 0 <= r["worst_frame"] < 24
    assert np.isfinite(r["flicker_windows_join_mean"]) and 0 < r["static_share"] <= 1
    assert "| composite | two windows |" in (out / "joins.md").read_text() and (out / "joins.png").stat().st_size > 5000
    stamp = (out / "composite" / "windows" / "report.json").stat().st_mtime
    assert main(argv) == 0
    assert (out / "composite" / "windows" / "report.json").stat().st_mtime == stamp  # finished runs reused
    assert json.loads((out / "joins.json").read_text())["runs"]["composite"]["windows"]["cached"]
