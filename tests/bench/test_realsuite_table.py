"""layercam.bench.realsuite.table: rows from the jobs' result.json files -> csv and markdown."""

from __future__ import annotations

import csv
import json

from layercam.bench.realsuite.cases import CASES
from layercam.bench.realsuite.table import CSV_FIELDS, collect_rows, write_table


def _result(out, case, tag, rows, code="abc1234"):
    d = out / "cases" / case / tag
    d.mkdir(parents=True)
    (d / "result.json").write_text(json.dumps({"rows": rows, "job": {"case": case}, "code": code}))


def test_table_rows_in_order_with_truth_kind_clipped_share_and_analysis(tmp_path):
    _result(tmp_path, "ntire-000000", "prepare", [])
    (tmp_path
     / "cases/ntire-000000/prepare/result.json").write_text(json.dumps({"rows": [],
        "job": {"case": "ntire-000000"}, "clipped_share": 0.125}))
    analysis = {"choice": "2 layer(s), blur 3x3 (s 5), tone learned, flow loss on",
                "reasons": {"layers": "independent motion in 100% of frame pairs"}}
    _result(tmp_path, "ntire-000000", "layercam-balanced",
            [{"method": "layercam", "preset": "balanced", "psnr_mu": 30.5, "wall_s": 100.0,
              "analysis": analysis}])
    _result(tmp_path, "ntire-000000", "layercam-fast",
            [{"method": "layercam", "preset": "fast", "psnr_mu": 29.0, "wall_s": 10.0,
              "analysis": analysis}])
    _result(tmp_path, "ntire-000000", "classical",
            [{"method": "debevec", "preset": "", "psnr_mu": 34.28, "wall_s": 0.1},
             {"method": "robertson", "preset": "", "psnr_mu": 31.3, "wall_s": 0.1}])
    _result(tmp_path, "taipei-3", "classical", [{"method": "debevec", "preset": "", "psnr_mu": 36.6, "wall_s": 0.1}])
    _result(tmp_path, "basler", "layercam-fast", [{"method": "layercam", "preset": "fast", "failed": "exit 2"}])
    _result(tmp_path, "not-a-case", "classical", [{"method": "x"}])
    rows = collect_rows(tmp_path, CASES)
    assert [(r["case"], r["method"], r["preset"]) for r in rows] == [
        ("ntire-000000", "debevec", ""), ("ntire-000000", "robertson", ""), ("ntire-000000", "layercam", "fast"),
        ("ntire-000000", "layercam", "balanced"), ("taipei-3", "debevec", ""), ("basler", "layercam", "fast")]
    assert rows[0]["clipped_pct"] == 12.5 and rows[0]["truth"] == "truth" and rows[4]["truth"] == "reference, not truth"

    write_table(tmp_path, rows, CASES, "layercam bench --suite real --out X")
    with open(tmp_path / "real_suite.csv") as f:
        got = list(csv.DictReader(f))
    assert list(got[0]) == CSV_FIELDS and len(got) == 6
    assert got[2]["analysis"] == analysis["choice"] and got[5]["failed"] == "exit 2"
    md = (tmp_path / "real_suite.md").read_text()
    assert "Regenerate: `layercam bench --suite real --out X`" in md and "abc1234" in md
    assert "a reference, not truth" in md and "| ntire-000000 | debevec |  | 34.28 |" in md
    assert "failed: exit 2" in md and "independent motion in 100% of frame pairs" in md
    # the targets, measured: layercam under Debevec here, and a dial that rises
    assert "| ntire-000000 | `fast` | PSNR-mu above OpenCV Debevec | 29.00 vs 34.28 (-5.28 dB) | **no** |" in md
    assert "| ntire-000000 | `fast -> balanced` | dial monotone (within 0.2 dB) | 29.00 -> 30.50 | yes |" in md
    # one markdown line per row: 4 table rows, 2 + 1 targets, 2 analysis rows
    assert sum(line.startswith("| ntire-000000 | ") for line in md.splitlines()) == 4 + 3 + 2
