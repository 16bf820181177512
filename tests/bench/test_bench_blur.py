"""``layercam bench --table blur`` (layercam.bench.blur): the blur generator's variants on synthetic scenes."""

from __future__ import annotations

import json

import numpy as np

from layercam.cli import main


def test_quick_blur_table_writes_shake_and_mfme(tmp_path, capsys):
    """--quick on a 32x32 shake clip and the 3-image stack, two seeds: every number measured, the
    seeds' mean and std from their own runs."""
    out = tmp_path / "blur"
    argv = ["bench", "--table", "blur", "--quick", "--cases", "shake,mfme-3", "--variants", "s5",
            "--seeds", "0,1", "--out", str(out)]
    assert main(argv) == 0
    shake = json.loads((out / "shake.json").read_text())
    assert len(shake["blur_length"]) == 4 and shake["largest"] == int(np.argmax(shake["blur_length"]))
    for kind in ("raw", "aligned"):
        for side in ("deblurred", "input"):
            assert np.isfinite(shake["s5"][kind][side]["psnr"]) and 0 < shake["s5"][kind][side]["ssim"] <= 1
        assert len(shake["s5"][kind]["per_frame"]["deblurred"]) == 4
    mfme = json.loads((out / "mfme.json").read_text())
    assert set(mfme) == {"3_s5", "3_s5_seed1", "3_s5_seeds"}
    vals = [mfme["3_s5"]["metrics"]["psnr_mu"], mfme["3_s5_seed1"]["metrics"]["psnr_mu"]]
    assert all(np.isfinite(vals)) and mfme["3_s5_seeds"]["mean"] == np.mean(vals)
    assert "two_stage_mfme (3 images)" in mfme["3_s5"]["baselines"]
    assert (out / "shake_s5").is_dir() and (out / "mfme_3_s5_seed1").is_dir()
    assert "wrote" in capsys.readouterr().out


def test_unknown_blur_case_or_variant_is_one_line_error(tmp_path, capsys):
    for argv in (["--cases", "mfme-4"], ["--variants", "s9"], ["--seeds", "a"]):
        assert main(["bench", "--table", "blur", "--quick", "--out", str(tmp_path / "b"), *argv]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error:") and len(err.strip().splitlines()) == 1
        assert argv[1] in err
    assert not (tmp_path / "b" / "shake.json").exists()
