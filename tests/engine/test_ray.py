"""Ray (``--ray``, layercam/engine/cluster.py): a batch of three tiny jobs and a three-window tiny clip run
as tasks on a local Ray instance of 2 CPUs, with outputs identical to the sequential run's.
Skipped when ``ray`` is not installed (``pip install -e '.[ray]'``)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from layercam.cli import main
from layercam.io import read_exr

from conftest import TINY, tiny_argv

ray = pytest.importorskip("ray", reason="ray is not installed: pip install -e '.[ray]' runs these tests")


@pytest.fixture(scope="module")
def local_ray():
    """One local Ray instance of 2 CPUs for the module (``--ray auto`` uses the one this process started)."""
    started = not ray.is_initialized()
    if started:
        import logging

        ray.init(num_cpus=2, num_gpus=0, include_dashboard=False, logging_level=logging.WARNING, log_to_driver=False)
    yield ray
    if started:
        ray.shutdown()


def _exrs(folder) -> dict:
    return {p.relative_to(folder).as_posix(): read_exr(p) for p in sorted(folder.glob("**/*.exr"))
            if p.relative_to(folder).parts[0] not in ("cache", "previous")}


def _same(a, b) -> None:
    ea, eb = _exrs(a), _exrs(b)
    assert sorted(ea) == sorted(eb) and ea
    for k in eb:
        assert np.array_equal(ea[k], eb[k]), k
    ra, rb = (json.loads((r / "report.json").read_text()) for r in (a, b))
    assert ra["cache_keys"] == rb["cache_keys"] and ra["train"]["steps"] == rb["train"]["steps"]


def test_batch_on_ray_matches_the_sequential_batch(local_ray, tmp_path, monkeypatch, capsys):
    from layercam import synth
    from layercam.io import write_png

    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    for name, seed in (("a", 1), ("b", 2), ("c", 3)):
        sc = synth.pan_hdr(frames=4, size=(32, 32), ev_step=3.0, seed=seed)
        (tmp_path / "seq" / "clips" / name).mkdir(parents=True)
        for t, f in enumerate(sc.clip.frames):
            write_png(tmp_path / "seq" / "clips" / name / f"f{t}.png", f)
    opts = "--ev-step 3 --preset fast --quiet " + " ".join(f"--set {s}" for s in TINY)
    (tmp_path / "seq" / "jobs.csv").write_text("command,input,output,options\n"
                                               + "".join(f"hdr-video,clips/{n},runs/{n},{opts}\n"
                                                         for n in "abc"))
    shutil.copytree(tmp_path / "seq", tmp_path / "ray")

    assert main(["batch", str(tmp_path / "seq" / "jobs.csv")]) == 0
    assert main(["batch", str(tmp_path / "ray" / "jobs.csv"), "--ray", "auto"]) == 0
    out = capsys.readouterr().out
    assert "3 done" in out and "[ray] cluster of 2 CPUs" in out, out
    for n in "abc":
        _same(tmp_path / "ray" / "runs" / n, tmp_path / "seq" / "runs" / n)
    assert main(["batch", str(tmp_path / "ray" / "jobs.csv"), "--ray", "auto"]) == 0  # restarted: all skipped
    assert "3 skipped" in capsys.readouterr().out


def test_windows_on_ray_match_the_sequential_run(local_ray, tmp_path, capsys):
    from layercam import synth
    from layercam.io import write_png

    frames = tmp_path / "frames"
    frames.mkdir()
    for t, f in enumerate(synth.pan_hdr(frames=12, size=(32, 32), ev_step=3.0, seed=1).clip.frames):
        write_png(frames / f"frame_{t:03d}.png", f)
    argv = lambda out, *x: tiny_argv("hdr-video", frames, out, "--ev-step", "3", "--window", "6", *x)  # noqa: E731
    assert main(argv(tmp_path / "seq")) == 0
    assert main(argv(tmp_path / "ray", "--ray", "auto")) == 0
    assert json.loads((tmp_path / "ray" / "report.json").read_text())["windows"]["ray"].startswith("cluster of 2 CPUs")
    assert len(json.loads((tmp_path / "ray" / "windows.json").read_text())["windows"]) == 3
    _same(tmp_path / "ray", tmp_path / "seq")
    import torch

    for k in range(3):
        a, b = (torch.load(r / "windows" / f"w{k:02d}" / "checkpoint.pt",
                           weights_only=False)["state"]
                for r in (tmp_path / "ray", tmp_path / "seq"))
        assert all(torch.equal(a[n], b[n]) for n in b)
