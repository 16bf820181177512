"""A long clip as overlapping windows (layercam.pipelines.windows): the plan, the shared camera, the join,
render and edit on a windowed run, and a windowed run interrupted anywhere (SIGKILL, Ctrl-C) that
finishes as if never interrupted."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from layercam.cli import main
from layercam.io import read_exr
from layercam.pipelines.windows import index as windows, plan as window_plan

from conftest import tiny_argv

FRAMES = 12
WINDOW = ("--window", "6")  # three windows of 6, 5 and 5 frames, overlapping by 2


@pytest.fixture(scope="module")
def long_frames(tmp_path_factory):
    """12 frames 32x32 of a pan, alternating 3 EV, as PNGs."""
    from layercam import synth
    from layercam.io import write_png

    folder = tmp_path_factory.mktemp("long") / "frames"
    folder.mkdir()
    for t, f in enumerate(synth.pan_hdr(frames=FRAMES, size=(32, 32), ev_step=3.0, seed=1).clip.frames):
        write_png(folder / f"frame_{t:03d}.png", f)
    return folder


def _argv(frames, out, *extra):
    return tiny_argv("hdr-video", frames, out, "--ev-step", "3", *WINDOW, *extra)


@pytest.fixture(scope="module")
def windowed(tmp_path_factory, long_frames):
    """The windowed run, never interrupted."""
    run = tmp_path_factory.mktemp("windowed") / "run"
    assert main(_argv(long_frames, run)) == 0
    return run


# -- the plan ----------------------------------------------------------------------------------------
def test_split_covers_the_clip_with_equal_overlaps():
    w = window_plan.split(96, 57, 2)
    assert w == [(0, 57), (39, 96)]
    p = window_plan.Plan(w, "")
    assert p.overlaps() == [18]  # a third of the window, whole exposure cycles
    assert p.weights(38) == [(0, 1.0)] and p.weights(96 - 1) == [(1, 1.0)]
    fades = [dict(p.weights(t))[1] for t in range(39, 57)]
    assert np.allclose(fades, np.arange(1, 19) / 19)  # a linear cross-fade, never 0 or 1 inside the overlap


@settings(max_examples=200, deadline=None)
@given(T=st.integers(4, 400), length=st.integers(3, 120), cycle=st.sampled_from([1, 2, 3]))
def test_any_split_joins_with_weights_that_sum_to_one(T, length, cycle):
    w = window_plan.split(T, length, cycle)
    p = window_plan.Plan(w, "")
    assert w[0][0] == 0 and w[-1][1] == T and all(b - a <= length for a, b in w)
    assert all(b1 > a2 for (_, b1), (a2, _) in zip(w, w[1:]))  # neighbours overlap
    for t in range(T):
        ws = p.weights(t)
        assert 1 <= len(ws) <= 2 and abs(sum(x for _, x in ws) - 1) < 1e-9 and all(0 < x <= 1 for _, x in ws)


def _clip_with_pan(T, step_px, hw=(32, 32)):
    from layercam.io import Exposures
    from layercam.io.clip import Clip
    from layercam.vision.flow_store import FlowArrays

    clip = Clip(np.zeros((T, *hw, 3), np.float32), "test", [str(t) for t in range(T)])
    homs = np.tile(np.eye(3), (T - 1, 1, 1))
    homs[:, 0, 2] = -step_px  # frame t+1 sees the scene moved left: the camera pans right
    flow = FlowArrays(fw=np.zeros((T - 1, *hw, 2), np.float16), homs=homs)
    return clip, Exposures(np.zeros(T), "none", None, "none", "test"), flow


def test_auto_plan_cuts_where_the_camera_leaves_the_atlas():
    from layercam.scene.layered import GRID_RES_RANGE

    GRID_MAX_RES = GRID_RES_RANGE[1]

    cap = GRID_MAX_RES
    clip, exp, flow = _clip_with_pan(120, 40.0)
    p = window_plan.plan(clip, exp, flow, "hdr-video")
    assert p.count > 1 and "it holds" in p.reason
    assert p.windows[0][0] == 0 and p.windows[-1][1] == 120
    for (a, b), px in zip(p.windows[:-1], p.atlas_px[:-1]):
        assert px <= cap and window_plan.atlas_px(flow.homs, a, b + 1, (32, 32)) > cap  # the longest that fits
    clip, exp, flow = _clip_with_pan(120, 0.0)  # a static camera: any length fits
    p = window_plan.plan(clip, exp, flow, "hdr-video")
    assert p.count == 1 and p.reason.startswith("one model")
    assert window_plan.plan(clip, exp, flow, "hdr-video", 0).count == 1
    assert window_plan.plan(clip, exp, flow, "hdr-video", 200).count == 1
    assert window_plan.plan(clip, exp, flow, "fuse-stack", 10).count == 1


# -- a windowed run -----------------------------------------------------------------------------------
def test_windowed_run_publishes_joined_outputs_and_each_window(windowed):
    top = sorted(p.name for p in windowed.iterdir())
    assert {"hdr", "preview.mp4", "crf.json", "windows", "windows.json", "report.json", "outputs.json"} <= set(top)
    assert "checkpoint.pt" not in top
    index = json.loads((windowed / "windows.json").read_text())
    spans = [tuple(w["frames"]) for w in index["windows"]]
    assert spans == [(0, 6), (4, 9), (7, 12)]
    assert len(list((windowed / "hdr").glob("*.exr"))) == FRAMES
    rep = json.loads((windowed / "report.json").read_text())
    assert "window" in rep["analysis"]["reasons"] and "--window 6" in rep["analysis"]["reasons"]["window"]
    assert [r["frames"] for r in rep["windows"]["runs"]] == [list(s) for s in spans]
    assert len(rep["train"]["windows"]) == 3 and rep["train"]["steps"] == 3 * 60


def test_windows_share_window_0s_camera(windowed):
    import torch

    states = [torch.load(windowed / "windows" / f"w{k:02d}" / "checkpoint.pt",
                         weights_only=False)["state"] for k in range(3)]
    tone = [k for k in states[0] if k.startswith("tone.")]
    assert tone
    for s in states[1:]:
        assert all(torch.equal(s[k], states[0][k]) for k in tone)
    assert not torch.equal(states[1]["scene.atlases.0.mlp.last.weight"],
                           states[0]["scene.atlases.0.mlp.last.weight"])  # each its own scene
    rep = json.loads((windowed / "report.json").read_text())
    keys = [r["keys"]["train"] for r in rep["windows"]["runs"]]
    material = json.loads((windowed / "cache" / "windows" / "00004-00009" / "cache"
                           / f"train-{keys[1]}" / "settings.json").read_text())
    assert material["options"]["camera"] == keys[0]  # the later windows' training names window 0's


def test_the_join_is_each_windows_hdr_cross_faded_over_the_overlap_by_their_fits_per_pixel(windowed):
    import cv2

    from layercam.camera.faithful import WINDOW_SIGMA
    from layercam.pipelines.windows.plan import FIT_FILE

    rep = json.loads((windowed / "report.json").read_text())
    exports = [windowed / "cache" / "windows" / f"{a:05d}-{b:05d}" / "cache"
               / f"export-{r['keys']['export']}" for r, (a, b) in
               zip(rep["windows"]["runs"], [(0, 6), (4, 9), (7, 12)])]
    own = lambda k, i: read_exr(exports[k] / "hdr" / f"frame_{i:05d}.exr")  # noqa: E731
    joined = lambda t: read_exr(windowed / "hdr" / f"frame_{t:05d}.exr")  # noqa: E731
    assert np.array_equal(joined(2), own(0, 2)) and np.array_equal(joined(6),
                          own(1, 2)) and np.array_equal(joined(11), own(2, 4))
    # each window's error per pixel over the overlap's frames 4, 5 (its own frames 4, 5 and 0, 1),
    # as its export measured it
    fit = [cv2.GaussianBlur(np.load(exports[k] / FIT_FILE)[i:i + 2].mean(0), (0, 0), WINDOW_SIGMA)
           for k, i in ((0, 4), (1, 0))]
    kept = np.load(windowed / "windows" / "fits.npz")
    assert np.allclose(kept["w0_o0"], fit[0]) and np.allclose(kept["w1_o0"], fit[1])
    # the two windows' fits differ from pixel to pixel
    assert not np.allclose(fit[0] / fit[1], (fit[0] / fit[1]).mean())
    for t, (i, j) in {4: (4, 0), 5: (5, 1)}.items():
        f = (t - 4 + 1) / 3  # the linear fade, each side divided by its window's error at the pixel
        w = ((f / fit[1]) / ((1 - f) / fit[0] + f / fit[1]))[..., None]
        assert ((w > 0) & (w < 1)).all() and ((w > f) == (fit[1] < fit[0])[..., None]).all()
        want = (1 - w) * own(0, i) + w * own(1, j)
        assert np.allclose(joined(t), want, rtol=2e-3, atol=1e-6)  # half floats


def test_render_on_a_windowed_run(windowed):
    from layercam.engine.checkpoint import load_run_model
    from layercam.scene.render import exposure_frames
    from layercam.io import read_image

    assert main(["render", str(windowed), "--exposure", "1", "--quiet"]) == 0
    out = windowed / "render" / "exposure_+1.00"
    assert len(list(out.glob("frame_*.png"))) == FRAMES
    models = [load_run_model(windowed / "windows" / f"w{k:02d}") for k in range(3)]
    z0 = windows.clip_reference([m for m, _ in models])
    own = exposure_frames(*models[1], 1.0, z0=z0)  # window 1 holds frames 6 alone
    assert np.abs(read_image(out / "frame_00006.png") - own[2]).max() <= 1 / 255 + 1e-6
    assert main(["render", str(windowed), "--sweep", "exposure", "--steps", "3", "--frame", "10", "--quiet"]) == 0


def test_edit_on_a_windowed_run_is_carried_to_every_window(windowed, tmp_path, capsys):
    import cv2

    png = cv2.imread(str(windowed / "windows" / "w01" / "atlases" / "layer0.png"), cv2.IMREAD_UNCHANGED)
    h, w = png.shape[:2]
    png[h // 3: 2 * h // 3, w // 3: 2 * w // 3] = (0, 0, 255, 255)
    cv2.imwrite(str(tmp_path / "edited.png"), png)
    assert main(["edit", str(windowed), "--layer", "0", "--atlas", str(tmp_path / "edited.png"), "--quiet"]) == 2
    assert "--window K" in capsys.readouterr().err
    assert main(["edit", str(windowed), "--layer", "0", "--atlas", str(tmp_path / "edited.png"),
                 "--window", "1", "--quiet", "--out", str(tmp_path / "edit")]) == 0
    info = json.loads((tmp_path / "edit" / "edit.json").read_text())
    painted = info["windows"][1]["edit_alpha_sum"]
    assert [w["edit"].split()[0] for w in info["windows"]] == ["carried", "painted", "carried"]
    # the patch is seen in every overlap
    assert all(0.5 * painted < w["edit_alpha_sum"] < 1.5 * painted for w in info["windows"])
    assert all(c > 0 for c in info["edit_visible_fraction_per_frame"])
    assert len(list((tmp_path / "edit" / "hdr").glob("*.exr"))) == FRAMES


# -- interrupted anywhere ------------------------------------------------------------------------------
NOT_OUTPUTS = {"cache", "previous", "layercam.lock", "render", "edit"}


def _exrs(folder) -> dict:
    rel = (p.relative_to(folder) for p in sorted(folder.glob("**/*.exr")))
    return {r.as_posix(): read_exr(folder / r) for r in rel if r.parts[0] not in NOT_OUTPUTS}


def assert_same_outputs(run, ref) -> None:
    """``run``'s top is ``ref``'s: the same names, EXR arrays (joined HDR, each window's atlases),
    checkpoints' weights, settings and keys."""
    import torch

    top = lambda r: sorted(p.name for p in r.iterdir() if p.name not in NOT_OUTPUTS)  # noqa: E731
    assert top(run) == top(ref)
    got, want = _exrs(run), _exrs(ref)
    assert sorted(got) == sorted(want) and len(want) >= FRAMES
    for name in want:
        assert np.array_equal(got[name], want[name]), name
    for ck in sorted(ref.glob("windows/*/checkpoint.pt")):
        a, b = (torch.load(r / ck.relative_to(ref), weights_only=False)["state"] for r in (run, ref))
        assert all(torch.equal(a[k], b[k]) for k in b), ck
    m, mr = (json.loads((r / "outputs.json").read_text()) for r in (run, ref))
    assert m["complete"] and m["key"] == mr["key"]
    rep, rr = (json.loads((r / "report.json").read_text()) for r in (run, ref))
    assert rep["cache_keys"] == rr["cache_keys"] and [r["keys"]
                                                      for r in rep["windows"]["runs"]] == [r["keys"]
                                                      for r in rr["windows"]["runs"]]


def _killed(frames, out, where: str) -> None:
    env = dict(os.environ, LAYERCAM_SIGNAL_AT=f"{where}:KILL")
    r = subprocess.run([sys.executable, "-m", "layercam", *_argv(frames, out)], env=env,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == -9, r.stderr[-3000:]


def test_sigkill_in_every_window_then_the_same_command_matches_an_uninterrupted_run(windowed, long_frames, tmp_path):
    """Killed in window 0's training (a resumed training passes its step again: the next kill is
    in its export), then in window 1's training and export, then in window 2's training, in the
    join and in publishing: each time the same command goes on from what the killed one left, and
    the last one finishes with the uninterrupted run's outputs."""
    import torch

    run = tmp_path / "run"
    for k in range(3):
        _killed(long_frames, run, "train:30")  # in window k: windows 0..k-1 finished
        cks = sorted(run.glob("cache/windows/*/cache/train-*/ckpt.pt"))
        # its last periodic checkpoint
        assert len(cks) == k + 1 and torch.load(cks[k], weights_only=False)["step"] == 20
        assert not list(run.glob("cache/windows/*/cache/export-*/done.json"))[k:]
        if k < 2:
            _killed(long_frames, run, "export:3")  # window k resumes, finishes training, killed exporting
    _killed(long_frames, run, "windows:5")  # the join, in the middle of the overlaps
    assert sorted(p.name for p in run.iterdir()) == ["cache", "layercam.lock"]  # nothing published yet
    _killed(long_frames, run, "publish:2")
    assert not json.loads((run / "outputs.json").read_text())["complete"]
    assert main(_argv(long_frames, run)) == 0
    assert_same_outputs(run, windowed)
    assert not list(run.glob(".publishing-*")) and not (run / "layercam.lock").exists()


@pytest.mark.parametrize("where", ["train:30", "windows:5"])
def test_ctrl_c_in_a_windowed_run_then_the_same_command_matches(windowed, long_frames, tmp_path, monkeypatch, where):
    run = tmp_path / "run"
    monkeypatch.setenv("LAYERCAM_SIGNAL_AT", f"{where}:INT")
    assert main(_argv(long_frames, run)) == 130
    monkeypatch.delenv("LAYERCAM_SIGNAL_AT")
    assert sorted(p.name for p in run.iterdir()) == ["cache"]
    assert main(_argv(long_frames, run)) == 0
    assert_same_outputs(run, windowed)


def test_switching_windows_off_sets_the_windowed_set_aside(windowed, long_frames, tmp_path):
    import shutil

    run = tmp_path / "run"
    shutil.copytree(windowed, run)
    key = json.loads((run / "outputs.json").read_text())["key"]
    assert main(tiny_argv("hdr-video", long_frames, run, "--ev-step", "3", "--window", "off")) == 0
    assert (run / "checkpoint.pt").is_file() and not (run / "windows").exists() and not (run / "windows.json").exists()
    assert (run / "previous" / key / "windows.json").is_file() and (run / "previous" / key
            / "windows" / "w02" / "checkpoint.pt").is_file()
    rep = json.loads((run / "report.json").read_text())
    assert rep["analysis"]["reasons"]["window"] == "off (--window 0)" and "windows" not in rep
    assert main(_argv(long_frames, run)) == 0  # back to the windows: from the cache, the same set
    assert_same_outputs(run, windowed)


def test_bad_window_values_are_one_line_errors(long_frames, tmp_path, capsys):
    for bad, says in (("2", ">= 3"), ("x", "expected an integer"), ("-1", ">= 3")):
        assert main(tiny_argv("hdr-video", long_frames, tmp_path / "r", "--window", bad)) == 2
        assert says in capsys.readouterr().err
    assert not (tmp_path / "r").exists()
    assert main(["demo", "--out", str(tmp_path / "d"), "--window", "4"]) == 2  # demo has no --window


def test_ray_without_ray_installed_is_one_line_before_any_work(long_frames, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray fails, as where it is not installed
    assert main(_argv(long_frames, tmp_path / "r", "--ray", "auto")) == 2
    err = capsys.readouterr().err
    assert "pip install 'layercam[ray]'" in err and err.count("\n") == 1
    assert not (tmp_path / "r").exists()
    (tmp_path / "jobs.csv").write_text("hdr-video,clip,run,\n")
    assert main(["batch", str(tmp_path / "jobs.csv"), "--ray", "auto"]) == 2
    assert "pip install 'layercam[ray]'" in capsys.readouterr().err


def test_deblur_video_windows_join_the_sharp_frames_and_alpha(long_frames, tmp_path):
    from layercam.io import read_image

    run = tmp_path / "run"
    assert main(tiny_argv("deblur-video", long_frames, run, "--blur", "off", "--layers", "2", *WINDOW)) == 0
    assert len(list((run / "frames").glob("*.png"))) == FRAMES and (run / "deblurred.mp4").is_file()
    assert len(list((run / "alpha").glob("*.png"))) == FRAMES
    rep = json.loads((run / "report.json").read_text())
    export = (run / rep["windows"]["runs"][1]["folder"] / "cache"
              / f"export-{rep['windows']['runs'][1]['keys']['export']}")
    assert np.array_equal(read_image(run / "frames" / "frame_00006.png"),
                          read_image(export / "frames" / "frame_00002.png"))  # window 1's alone
    assert np.array_equal(read_image(run / "alpha" / "frame_00006.png"),
                          read_image(export / "alpha" / "frame_00002.png"))
    assert np.array_equal(read_image(run / "trust" / "frame_00006.png"),
                          read_image(export / "trust" / "frame_00002.png"))  # the trust masks too
    assert len(list((run / "trust").glob("*.png"))) == FRAMES
    assert (run / "windows" / "w02" / "atlases" / "layer1.png").is_file()


def test_overlap_weights_follow_the_windows_fits(tmp_path):
    """Equal fits keep the linear fade; where a window fits the overlap four times better (a quarter
    of the error) it takes four times its fade's share, pixel by pixel; frames outside an overlap
    are one window's alone; without the frame's size, or without fits, the plain fade."""
    p = window_plan.Plan([(0, 6), (4, 9)], "test")
    assert np.allclose([w for _, w in p.weights(4, (2, 3))], [2 / 3, 1 / 3])
    e0, e1 = np.full((2, 3), 0.01, np.float32), np.full((2, 3), 0.01, np.float32)
    e1[0, 0] = 0.0025
    p.fits = {(0, 0): e0, (1, 0): e1}
    w = dict(p.weights(4, (2, 3)))
    assert np.allclose(w[0] + w[1], 1.0) and np.allclose(w[1][1:], 1 / 3) and np.allclose(w[1][0, 1:], 1 / 3)
    assert np.isclose(w[1][0, 0] / w[0][0, 0], 4 * (1 / 3) / (2 / 3))
    assert dict(p.weights(4, (4, 6)))[1].shape == (4, 6)  # the fits at the frame's size
    assert np.allclose([w for _, w in p.weights(4)], [2 / 3, 1 / 3])
    assert p.weights(2, (2, 3)) == [(0, 1.0)] and p.weights(7, (2, 3)) == [(1, 1.0)]
    (tmp_path / "windows").mkdir()
    np.savez(tmp_path / "windows" / "fits.npz", w0_o0=e0, w1_o0=e1)
    back = windows.index_plan({"windows": [{"index": 0, "frames": [0, 6]}, {"index": 1, "frames": [4, 9]}]}, tmp_path)
    assert all(np.array_equal(a, b) for (_, a), (_, b) in zip(back.weights(5, (2, 3)), p.weights(5, (2, 3))))
