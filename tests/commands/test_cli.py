"""The command line: help is instant and complete; bad input gets one line and exit code 2."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from layercam.cli import main

from conftest import SMALL_BLUR, TINY


def test_help_lists_commands(capsys):
    assert main([]) == 0
    out = capsys.readouterr().out
    for cmd in ["hdr-video", "demo"]:
        assert cmd in out


def test_help_does_not_import_torch():
    code = "import sys; from layercam.cli import build_parser; build_parser(); print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["hdr-video", "nope.mp4"], "nope.mp4"),
        (["hdr-video", "{video}", "--exposures", "0,3,x"], "exposure"),
        (["hdr-video", "{video}", "--set", "train.stepz=3"], "stepz"),
        (["hdr-video", "{video}", "--preset", "ludicrous"], "ludicrous"),
        (["hdr-video", "{corrupt}"], "corrupt"),
    ],
)
def test_bad_input_one_line_exit_2(argv, needle, tmp_path, capsys):
    from layercam.io import write_video

    video = tmp_path / "v.mp4"
    write_video(video, np.random.default_rng(0).random((4, 16, 16, 3)).astype(np.float32), fps=4)
    corrupt = tmp_path / "corrupt.mp4"
    corrupt.write_bytes(b"\x00not a video" * 50)
    argv = [a.format(video=video, corrupt=corrupt) for a in argv] + ["--out", str(tmp_path / "run"), "--quiet"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "\n" not in err
    assert needle in err.lower() or needle in err


def test_hdr_video_on_a_real_mp4_with_a_blur_generator_writes_psf_json(tmp_path, tiny_scene):
    import json

    from layercam.io import write_video

    video = tmp_path / "clip.mp4"
    write_video(video, tiny_scene.clip.frames, fps=8)
    argv = ["hdr-video", str(video), "--exposures", "alt", "--ev-step", "3", "--blur", "3x3",
            "--out", str(tmp_path / "run"), "--preset", "fast", "--quiet"]
    for s in TINY + SMALL_BLUR + ["train.steps=20"]:
        argv += ["--set", s]
    assert main(argv) == 0
    run = tmp_path / "run"
    assert len(list((run / "hdr").glob("*.exr"))) == 4 and (run / "atlases" / "atlas.json").is_file()
    psf = json.loads((run / "psf.json").read_text())
    assert len(psf["spread_px"]) == len(psf["frames"]) == tiny_scene.clip.T
    rep = json.loads((run / "report.json").read_text())
    assert rep["analysis"]["blur"] == "3x3" and rep["export"]["psf"]["spread_px"] == psf["spread_px"]
