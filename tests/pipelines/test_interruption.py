"""Runs that survive interruption: Ctrl-C (SIGINT) or SIGKILL at an exact point of training, export,
the atlases or publishing, then the same command again: it finishes, and its outputs are those of
a run that was never interrupted (identical EXR arrays). Over a finished run, the top of the run
folder stays one consistent set throughout; switching settings A -> B -> A puts A's outputs back.

The interruption comes from the ``LAYERCAM_SIGNAL_AT="where:i:SIG"`` hook (layercam/core/interrupts.py):
the process signals itself when it reaches item ``i`` of ``where``, so the point is exact and does
not depend on timing. SIGKILL runs are subprocesses; Ctrl-C runs go through ``main`` in this process.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from layercam.cli import main
from layercam.io import read_exr

from conftest import tiny_argv

ARGS = ("--ev-step", "3")


def _argv(frames, out, *extra):
    return tiny_argv("hdr-video", frames, out, *ARGS, *extra)


def _killed(frames, out, where: str, *extra) -> None:
    """The command, SIGKILLed when it reaches ``where`` ("export:2")."""
    env = dict(os.environ, LAYERCAM_SIGNAL_AT=f"{where}:KILL")
    r = subprocess.run([sys.executable, "-m", "layercam", *_argv(frames, out, *extra)], env=env,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == -9, r.stderr[-3000:]


def _ctrl_c(frames, out, where: str, monkeypatch, *extra) -> None:
    monkeypatch.setenv("LAYERCAM_SIGNAL_AT", f"{where}:INT")
    assert main(_argv(frames, out, *extra)) == 130
    monkeypatch.delenv("LAYERCAM_SIGNAL_AT")


NOT_OUTPUTS = {"cache", "previous", "layercam.lock", "render", "edit"}


def _exrs(folder) -> dict:
    rel = (p.relative_to(folder) for p in sorted(folder.glob("**/*.exr")))
    return {r.as_posix(): read_exr(folder / r) for r in rel if r.parts[0] not in NOT_OUTPUTS}


def _top(run, outputs_only: bool = False) -> list[str]:
    return sorted(p.name for p in run.iterdir() if not (outputs_only and p.name in NOT_OUTPUTS))


def _assert_same_outputs(run, ref) -> None:
    """``run``'s top level is ``ref``'s: the same names, the same EXR arrays (HDR frames and
    atlases), the same settings in the report and a complete outputs.json under the same key."""
    assert _top(run, True) == _top(ref, True)
    got, want = _exrs(run), _exrs(ref)
    assert sorted(got) == sorted(want) and len(want) >= 5
    for name in want:
        assert np.array_equal(got[name], want[name]), name
    m, mr = (json.loads((r / "outputs.json").read_text()) for r in (run, ref))
    assert m["complete"] and m["key"] == mr["key"]
    rep, rr = (json.loads((r / "report.json").read_text()) for r in (run, ref))
    assert rep["cache_keys"] == rr["cache_keys"] and rep["train"]["steps"] == rr["train"]["steps"]


@pytest.fixture(scope="module")
def reference(tmp_path_factory, tiny_frames):
    """The same command, never interrupted."""
    ref = tmp_path_factory.mktemp("reference") / "run"
    assert main(_argv(tiny_frames, ref)) == 0
    return ref


@pytest.mark.parametrize("where", ["decode:2", "flow:1", "train:30", "export:2", "atlas:1", "publish:2"])
def test_sigkill_then_the_same_command_matches_an_uninterrupted_run(reference, tiny_frames, tmp_path, where):
    run = tmp_path / "run"
    _killed(tiny_frames, run, where)
    top = _top(run)
    if where == "publish:2":  # two names placed: the folder says which set and that it is not whole
        m = json.loads((run / "outputs.json").read_text())
        assert not m["complete"] and top.count("hdr") == 1
    elif where == "decode:2":  # killed while decoding the frames: before the lock, a partial decode in the cache
        assert top == ["cache"] and [p.name.startswith(".frames-") for p in (run / "cache").iterdir()] == [True], top
    else:  # nothing at the top but the cache and the lock the killed command held
        assert top == ["cache", "layercam.lock"], top
    if where == "train:30":
        import torch

        (ck,) = run.glob("cache/train-*/ckpt.pt")
        assert torch.load(ck, weights_only=False)["step"] == 20  # the last periodic checkpoint
    assert main(_argv(tiny_frames, run)) == 0
    _assert_same_outputs(run, reference)
    assert not list((run / "cache").glob(".frames-*")), "the killed decode's partial folder was left"
    rep = json.loads((run / "report.json").read_text())
    if where == "train:30":
        assert rep["train"]["resumed_from"] == 20
    assert not list(run.glob(".publishing-*")) and not (run / "layercam.lock").exists()


@pytest.mark.parametrize("where", ["decode:2", "flow:1", "train:30", "export:2"])
def test_ctrl_c_then_the_same_command_matches_an_uninterrupted_run(reference, tiny_frames, tmp_path,
    monkeypatch, capsys, where):
    run = tmp_path / "run"
    _ctrl_c(tiny_frames, run, where, monkeypatch)
    assert "interrupted: run the same command again" in capsys.readouterr().err
    if where == "decode:2":  # before any stage: the folder it made is gone again
        assert not run.exists()
    else:
        assert _top(run) == ["cache"]  # the lock is released, nothing half-written at the top
    assert main(_argv(tiny_frames, run)) == 0
    _assert_same_outputs(run, reference)
    if where == "train:30":  # Ctrl-C saved a checkpoint at the step it stopped at
        assert json.loads((run / "report.json").read_text())["train"]["resumed_from"] == 30


def test_settings_a_b_a_over_a_finished_run(reference, tiny_frames, tmp_path, monkeypatch):
    """Issue 18 items 1 and 3: B's export killed over A's finished run leaves A whole at the top;
    B finishes; A again puts A's outputs (and report) back; previous/ keeps what was replaced."""
    run = tmp_path / "run"
    shutil.copytree(reference, run)
    a_key = json.loads((run / "outputs.json").read_text())["key"]
    b = ("--set", "export.half=false")  # another export: training stays cached
    assert main(["render", str(run), "--exposure", "1", "--quiet"]) == 0  # made from A's checkpoint

    _killed(tiny_frames, run, "export:1", *b)  # (its lock file stays: the next command takes it over)
    _assert_same_outputs(run, reference)  # A, whole

    _ctrl_c(tiny_frames, run, "export:2", monkeypatch, *b)
    _assert_same_outputs(run, reference)  # still A, whole

    assert main(_argv(tiny_frames, run, *b)) == 0
    m = json.loads((run / "outputs.json").read_text())
    assert m["complete"] and m["key"] != a_key
    rep = json.loads((run / "report.json").read_text())
    assert rep["settings"]["export"]["half"] is False and rep["export"]["exr"] == "float32"  # B's
    assert not np.array_equal(read_exr(run / "hdr" / "frame_00000.exr"),
                              read_exr(reference / "hdr" / "frame_00000.exr"))
    _assert_same_outputs(run / "previous" / a_key, reference)  # A kept, as a whole set
    assert not (run / "render").exists() and (run / "previous" / a_key / "render" / "exposure_+1.00"
                / "render.json").is_file()

    assert main(_argv(tiny_frames, run)) == 0  # A again: restored from its cache
    rep = json.loads((run / "report.json").read_text())
    assert rep["settings"]["export"]["half"] is True and all(t["cached"] for t in rep["stages"].values())
    _assert_same_outputs(run, reference)
    assert (run / "render" / "exposure_+1.00" / "render.json").is_file()  # A's render came back with A
    assert (run / "previous" / m["key"] / "outputs.json").is_file()  # B kept
    assert len(list((run / "previous" / m["key"] / "hdr").glob("*.exr"))) == 4
