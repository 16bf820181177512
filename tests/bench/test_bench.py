"""``layercam bench``: the --quick smoke test of both tables, and the speed-up arithmetic.

Speed goals are measured by the benchmark itself (README, docs/bench/); nothing here asserts a time."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from layercam.bench.analysis import run_analysis_table
from layercam.bench.synthetic import speedups, time_to_reach
from layercam.cli import main


def test_time_to_reach_interpolates_and_gives_up():
    curve = [{"train_s": 10.0, "psnr_mu": 20.0}, {"train_s": 20.0, "psnr_mu": 30.0}]
    assert time_to_reach(curve, 25.0) == pytest.approx(15.0)
    assert time_to_reach(curve, 15.0) == 10.0  # reached by the first probe: its time (an upper bound)
    assert time_to_reach(curve, 31.0) is None


def test_speedups_against_the_paper_curve():
    curves = {
        ("pan", "paper"): [{"train_s": 100.0, "psnr_mu": 20.0}, {"train_s": 200.0, "psnr_mu": 25.0}],
        ("pan", "fast"): [{"train_s": 1.0, "psnr_mu": 22.0}, {"train_s": 2.0, "psnr_mu": 30.0}],
        ("pan", "slow"): [{"train_s": 500.0, "psnr_mu": 24.0}],
    }
    s = speedups(curves, [])["pan"]
    assert s["target_psnr_mu"] == 25.0 and s["paper_s"] == 200.0
    assert s["fast"]["seconds"] == pytest.approx(1.375) and s["fast"]["speedup"] == pytest.approx(200 / 1.375)
    assert s["slow"]["seconds"] is None and s["slow"]["speedup"] is None


@pytest.mark.timeout(900)  # one process per preset, the paper preset's 4x512 atlas included
def test_quick_bench_writes_csv_plot_and_speedups(tmp_path, capsys):
    out = tmp_path / "bench"
    assert main(["bench", "--quick", "--out", str(out), "--presets", "fast,paper", "--threads", "1"]) == 0
    rows = list(csv.DictReader(open(out / "bench.csv")))
    assert [(r["method"], r["preset"]) for r in rows] == [("debevec", ""), ("layercam", "fast"), ("layercam", "paper")]
    for r in rows:
        assert np.isfinite(float(r["psnr_mu"])) and float(r["wall_s"]) > 0 and float(r["peak_mem_mb"]) > 0
    assert all(float(r["steps_per_s"]) > 0 for r in rows[1:])
    assert (out / "bench.png").stat().st_size > 1000
    sp = json.loads((out / "speedups.json").read_text())
    assert "fast" in sp["pan"]
    assert "PSNR-mu" in capsys.readouterr().out


def test_a_preset_file_runs_under_its_stem(tmp_path):
    """``--presets my.toml`` (an absolute path): its run folder and result are named by the file's
    stem (the path joined as a folder had made the run folder the preset file itself)."""
    preset = tmp_path / "mine.toml"
    preset.write_text("[train]\nsteps = 600\n[tone]\nwidth = 48\n")
    out = tmp_path / "bench"
    assert main(["bench", "--quick", "--out", str(out), "--presets", str(preset), "--threads", "1"]) == 0
    assert (out / "pan" / "mine").is_dir() and preset.read_text().startswith("[train]")
    rows = [r for r in csv.DictReader(open(out / "bench.csv")) if r["method"] == "layercam"]
    assert len(rows) == 1 and rows[0]["preset"].endswith("mine.toml")


def test_a_setting_reaches_every_preset_job(tmp_path):
    """``--set KEY=VALUE`` (here a training seed, for a spread over seeds) reaches each preset's run
    and is written in the row's note."""
    out = tmp_path / "bench"
    assert main(["bench", "--quick", "--out", str(out), "--presets", "fast", "--threads", "1",
                 "--set", "train.seed=3", "--quiet"]) == 0
    report = json.loads((out / "pan" / "fast" / "report.json").read_text())
    assert report["settings"]["train"]["seed"] == 3
    rows = [r for r in csv.DictReader(open(out / "bench.csv")) if r["method"] == "layercam"]
    assert "train.seed=3" in rows[0]["note"]


def test_unknown_bench_scene_is_one_line_error(tmp_path, capsys):
    assert main(["bench", "--quick", "--out", str(tmp_path / "b"), "--scenes", "nope"]) == 2
    err = capsys.readouterr().err
    assert "unknown bench scene" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("argv, says", [
    (["--table", "layers", "--cases", "goat"], "--cases is not read by --table layers (it reads --clips"),
    (["--table", "joins", "--clips", "cows"], "--clips is not read by --table joins"),
    (["--suite", "real", "--table", "layers"], "--suite real and --table layers are two benchmarks"),
    (["--suite", "real", "--seeds", "0,1"], "--seeds is not read by --suite real"),
])
def test_an_option_the_bench_does_not_read_is_one_line_error(tmp_path, capsys, argv, says):
    """Given to a suite or table that ignores it (``--cases`` for the layers table, whose clips are
    ``--clips``), an option is refused before any work, not silently dropped."""
    out = tmp_path / "b"
    assert main(["bench", "--out", str(out), *argv]) == 2
    err = capsys.readouterr().err
    assert says in err and len(err.strip().splitlines()) == 1 and not out.exists()


def test_quick_analysis_table_chosen_against_full(tmp_path):
    rows = run_analysis_table(tmp_path / "an", quick=True, families=["static", "shake"], progress=False)
    by = {(r["family"], r["variant"]): r for r in rows}
    assert set(by) == {("static", "chosen"), ("static", "full"), ("shake", "chosen"), ("shake", "full")}
    # the analysis keeps the static, single-exposure, sharp clip minimal; the full model is forced
    assert by["static", "chosen"]["layers"] == 1 and by["static", "chosen"]["blur"] == "off"
    assert by["static", "chosen"]["tone_mapper"] == "fixed"
    assert by["static", "full"]["layers"] == 2 and by["static", "full"]["blur"] == "3x3"
    assert by["shake", "chosen"]["blur"] != "off"
    assert all(np.isfinite(r["value"]) and r["reasons"] for r in rows)
    md = (tmp_path / "an" / "analysis_table.md").read_text()
    assert md.count("\n") == 2 + len(rows)


@pytest.mark.timeout(600)  # a process per clip, run, score and baseline
def test_scaling_table_writes_csv_and_plot(tmp_path, capsys):
    """``bench --table scaling`` on two tiny sizes: a row per size and method, costs and quality measured."""
    out = tmp_path / "sc"
    argv = ["bench", "--table", "scaling", "--out", str(out), "--sizes", "16x16,24x32", "--frames",
            "4", "--presets", "fast",
            "--threads", "1", "--set", "train.steps=30"]
    assert main(argv) == 0
    rows = list(csv.DictReader(open(out / "scaling.csv")))
    assert [(r["size"], r["method"]) for r in rows] == [("16x16", "debevec"), ("16x16", "layercam"),
                                                        ("24x32", "debevec"), ("24x32", "layercam")]
    for r in rows:
        assert float(r["wall_s"]) > 0 and float(r["peak_mem_mb"]) > 0 and np.isfinite(float(r["psnr_mu"]))
    lc = [r for r in rows if r["method"] == "layercam"]
    assert all(int(r["steps"]) == 30 and float(r["steps_per_s"]) > 0 and float(r["train_s"]) > 0 for r in lc)
    assert [int(r["pixels"]) for r in lc] == [256, 768]
    assert (out / "scaling.png").stat().st_size > 1000
    again = ["bench", "--table", "scaling", "--out", str(out), "--sizes", "16x16", "--frames", "4",
             "--presets", "balanced",
             "--no-baseline", "--threads", "1", "--set", "train.steps=20", "--quiet"]
    assert main(again) == 0  # a later run adds its rows to the table
    rows = list(csv.DictReader(open(out / "scaling.csv")))
    assert [(r["size"], r["method"], r["preset"]) for r in rows][:3] == [("16x16", "debevec", ""),
        ("16x16", "layercam", "fast"), ("16x16", "layercam", "balanced")]
    assert len(rows) == 5 and rows[2]["steps"] == "20"
    assert main(["bench", "--table", "scaling", "--out", str(out), "--sizes", "4x4"]) == 2
    assert "sizes start at 8x8" in capsys.readouterr().err
