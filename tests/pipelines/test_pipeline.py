"""End to end on tiny clips: the stage cache skips, invalidates and resumes; outputs are sane."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, strategies as st

from layercam.core.presets import load_config
from layercam.io import read_exr
from layercam.pipelines.tasks import run_task

from conftest import TINY
from props import SIZES, Z, props


def _run(scene, exposures, out, extra=()):
    cfg = load_config("fast", TINY + list(extra))
    return run_task("hdr-video", scene.clip, exposures, cfg, out, progress=False)


def test_end_to_end_outputs_and_loss_falls(tiny_scene, tiny_exposures, tmp_path):
    ctx = _run(tiny_scene, tiny_exposures, tmp_path / "run")
    run = tmp_path / "run"
    for name in ["preview.mp4", "crf.json", "crf.png", "report.json", "checkpoint.pt"]:
        assert (run / name).is_file(), name
    exrs = sorted((run / "hdr").glob("frame_*.exr"))
    assert len(exrs) == tiny_scene.clip.T
    for p in exrs:
        img = read_exr(p)
        assert img.shape == (32, 32, 3)
        assert np.isfinite(img).all() and (img >= 0).all()
    rep = json.loads((run / "report.json").read_text())
    tr = rep["train"]
    assert tr["final_loss"]["color"] < 0.5 * tr["first_loss"]["color"]
    assert rep["analysis"]["layers"] == 1 and rep["analysis"]["tone_mapper"] == "learned"
    est = rep["memory"]["estimate"]  # after the analysis: the model the run built (its atlas sized
                                     # by the pan); before: an upper bound
    assert est["after_analysis"]["params"] == sum(p.numel() for p in ctx.model.parameters()) < est["before"]["params"]
    if Path("/proc/self/clear_refs").exists():  # each stage's own peak resident memory, within the run's
        peaks = {k: v["peak_mb"] for k, v in rep["stages"].items() if not v.get("cached")}
        assert set(peaks) >= {"flow", "train",
                              "export"} and all(0 < v <= rep["memory"]["peak_rss_bytes"] / 2**20 + 4
                                                for v in peaks.values()), (peaks,
                              rep["memory"]["peak_rss_bytes"] / 2**20)  # the kernel counts lazily
    crf = json.loads((run / "crf.json").read_text())
    assert len(crf["r"]) == len(crf["z_stops"])


def test_same_command_skips_changed_setting_redoes_dependents(tiny_scene, tiny_exposures, tmp_path):
    from layercam.pipelines.hdr_frames import faithful_hdr

    run = tmp_path / "run"
    first = _run(tiny_scene, tiny_exposures, run)
    trained = first.model
    ctx = _run(tiny_scene, tiny_exposures, run)
    assert all(t["cached"] for t in ctx.times.values())
    # a cached stage reports the peak memory it had when it ran
    assert all(t.get("original_peak_mb") == first.times[k].get("peak_mb") for k, t in ctx.times.items())
    # an export setting: the model is rebuilt once from the cached training, and renders what the trained one did
    ctx = _run(tiny_scene, tiny_exposures, run, ["export.half=off"])
    assert ctx.times["train"]["cached"] and not ctx.times["export"]["cached"] and ctx.model is not trained
    for t, expect, _ in faithful_hdr(ctx, trained, range(tiny_scene.clip.T)):
        # export.faithful: corrected towards the frames
        np.testing.assert_array_equal(read_exr(run / "hdr" / f"frame_{t:05d}.exr"), expect)
    ctx = _run(tiny_scene, tiny_exposures, run, ["train.steps=70"])
    assert ctx.times["flow"]["cached"] and ctx.times["bootstrap"]["cached"]
    assert not ctx.times["train"]["cached"] and not ctx.times["export"]["cached"]
    # the earlier export was set aside, not overwritten
    prev = list((run / "previous").glob("*/report.json"))
    assert prev, "earlier outputs should be kept under previous/"
    ctx = _run(tiny_scene, tiny_exposures, run, ["flow.method=dis_medium"])
    assert not ctx.times["flow"]["cached"] and not ctx.times["train"]["cached"]


def test_interrupted_training_resumes(tiny_scene, tiny_exposures, tmp_path, monkeypatch):
    run = tmp_path / "run"
    monkeypatch.setenv("LAYERCAM_SIGNAL_AT", "train:45:INT")  # Ctrl-C at step 45
    with pytest.raises(KeyboardInterrupt):
        _run(tiny_scene, tiny_exposures, run)
    monkeypatch.delenv("LAYERCAM_SIGNAL_AT")
    ckpts = list((run / "cache").glob("train-*/ckpt.pt"))
    assert len(ckpts) == 1
    ctx = _run(tiny_scene, tiny_exposures, run)
    assert ctx.results["train"].resumed_from == 45
    assert ctx.results["train"].steps == 60
    assert ctx.times["flow"]["cached"]


def test_foreign_files_in_run_folder_are_not_overwritten(tiny_scene, tiny_exposures, tmp_path):
    from layercam.core.errors import LayercamError

    run = tmp_path / "run"
    run.mkdir()
    (run / "preview.mp4").write_bytes(b"somebody else's video")
    with pytest.raises(LayercamError):
        _run(tiny_scene, tiny_exposures, run)
    assert (run / "preview.mp4").read_bytes() == b"somebody else's video"


E2E = TINY + ["train.steps=6", "train.batch=64", "train.bootstrap_steps=2", "train.checkpoint_every=3"]


def _frames(content: str, t: int, hw: tuple[int, int], value: float) -> np.ndarray:
    rng = np.random.default_rng(t * 100 + hw[0])
    shape = (t, *hw, 3)
    if content == "black":
        return np.zeros(shape, np.float32)
    if content == "white":
        return np.ones(shape, np.float32)
    if content == "constant":
        return np.full(shape, value, np.float32)
    return rng.random(shape).astype(np.float32)


def _load_png16(frames: np.ndarray, d: Path, grey: bool):
    from layercam.io import load_clip, write_png

    for i, f in enumerate(frames):
        write_png(d / f"f{i:02d}.png", f.mean(-1) if grey else f, bit_depth=16)  # (H, W) grey or RGB, 16 bit
    clip = load_clip(d)
    assert clip.bit_depth == 16 and clip.frames.shape == frames.shape
    assert np.allclose(clip.frames, frames.mean(-1, keepdims=True) if grey else frames, atol=1e-4)
    return clip


# tiny clips through the whole hdr-video pipeline (1x1, 2x3, odd sizes, one frame, black / white /
# constant frames, 16-bit grey PNGs): the exported EXRs are finite and non-negative, the curves finite
# (and monotone for the fixed curve); the named extremes always run, hypothesis adds random combinations
@example(hw=(1, 1), t=1, content="black", value=0.0, ev=0, learn=False, robust=0.0, autocast="none")
@example(hw=(1, 1), t=3, content="white", value=0.0, ev=-12, learn=False, robust=0.05, autocast="none")
@example(hw=(2, 3), t=2, content="constant", value=0.5, ev=12, learn=True, robust=0.0, autocast="bf16")
@example(hw=(5, 7), t=3, content="grey16", value=0.0, ev=12, learn=False, robust=0.05, autocast="none")
@example(hw=(7, 5), t=2, content="rgb16", value=0.0, ev=-12, learn=False, robust=0.0, autocast="bf16")
@example(hw=(2, 3), t=2, content="white", value=0.0, ev=12, learn=False, robust=0.0, autocast="none")
@props(6)
@given(
    hw=SIZES,
    t=st.integers(1, 3),
    content=st.sampled_from(["black", "white", "constant", "random", "grey16", "rgb16"]),
    value=st.floats(0, 1),
    ev=st.integers(-12, 12),
    learn=st.booleans(),
    robust=st.sampled_from([0.0, 0.05]),
    autocast=st.sampled_from(["none", "bf16"]),
)
def test_end_to_end_tiny_clips_export_finite_hdr_and_monotone_curves(hw, t, content, value, ev,
    learn, robust, autocast):
    from layercam.io import Clip, Exposures, read_exr
    from layercam.core.presets import load_config
    from layercam.pipelines.tasks import run_task

    frames = _frames("random" if content.endswith("16") else content, t, hw, value)
    log2 = np.where(np.arange(t) % 2 == 1, float(ev), 0.0)
    learn = learn and t > 1
    cfg = load_config("fast", E2E + [f"loss.robust={robust}", f"train.autocast={autocast}"])
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        if content.endswith("16"):
            (d / "in").mkdir()
            clip = _load_png16(frames, d / "in", grey=content == "grey16")
        else:
            clip = Clip(frames=frames, source=f"test:{content}", names=[f"{i}" for i in range(t)])
        ex = Exposures(log2, "ratio" if learn else "none", np.arange(t) % 2, "alt", "test")
        run_task("hdr-video", clip, ex, cfg, d / "run", progress=False)
        exrs = sorted((d / "run" / "hdr").glob("frame_*.exr"))
        assert len(exrs) == t
        for p in exrs:
            img = read_exr(p)
            assert img.shape == (*hw, 3) and np.isfinite(img).all() and (img >= 0).all()
        rep = json.loads((d / "run" / "report.json").read_text())
        assert rep["train"]["steps"] == 6 and np.isfinite(rep["train"]["log2_dt"]).all()
        from layercam.engine.checkpoint import load_run_model

        model, _ = load_run_model(d / "run")
        curve = model.tone.curve(Z).numpy()
        assert np.isfinite(curve).all() and curve.min() >= 0 and curve.max() <= 1
        if rep["analysis"]["tone_mapper"] == "fixed":
            assert (np.diff(curve, axis=0) >= 0).all(), "CRF not monotone over [-20, 20] stops"


def test_run_folders_of_earlier_versions_are_set_aside(tiny_scene, tiny_exposures, tmp_path):
    """A finished run of an earlier version (export_key.txt) and one whose export was interrupted
    (outputs without a key, next to its cache) are moved to previous/, not refused or overwritten."""
    marked, unmarked = tmp_path / "marked", tmp_path / "unmarked"
    for run in (marked, unmarked):
        (run / "hdr").mkdir(parents=True)
        (run / "hdr" / "frame_00000.exr").write_bytes(b"earlier")
        (run / "atlases").mkdir()
    (marked / "export_key.txt").write_text("abc123")
    (marked / "report.json").write_text("{}")
    (unmarked / "cache").mkdir()
    for run in (marked, unmarked):
        _run(tiny_scene, tiny_exposures, run)
        assert len(list((run / "hdr").glob("*.exr"))) == tiny_scene.clip.T
    assert (marked / "previous" / "abc123" / "hdr" / "frame_00000.exr").read_bytes() == b"earlier"
    assert (marked / "previous" / "abc123" / "export_key.txt").is_file() and not (marked / "export_key.txt").exists()
    (kept,) = (unmarked / "previous").glob("unmarked-*")
    assert (kept / "hdr" / "frame_00000.exr").read_bytes() == b"earlier" and (kept / "atlases").is_dir()


def test_outputs_lost_from_the_cache_are_made_again(tiny_scene, tiny_exposures, tmp_path):
    import shutil

    run = tmp_path / "run"
    _run(tiny_scene, tiny_exposures, run)
    (hdr,) = run.glob("cache/export-*/hdr")
    shutil.rmtree(hdr)
    shutil.rmtree(run / "hdr")
    ctx = _run(tiny_scene, tiny_exposures, run)
    assert ctx.times["train"]["cached"] and not ctx.times["export"]["cached"]
    assert len(list((run / "hdr").glob("*.exr"))) == tiny_scene.clip.T


def test_settings_a_b_a_puts_a_back(tiny_scene, tiny_exposures, tmp_path):
    """Issue 18 item 3: settings A, then B, then A again: the top of the run folder is A's again
    (outputs and report), not B's under A's report; previous/ keeps B's."""
    run = tmp_path / "run"
    _run(tiny_scene, tiny_exposures, run)
    a = [read_exr(p) for p in sorted((run / "hdr").glob("*.exr"))]
    _run(tiny_scene, tiny_exposures, run, ["export.half=false"])
    b = [read_exr(p) for p in sorted((run / "hdr").glob("*.exr"))]
    assert json.loads((run / "report.json").read_text())["export"]["exr"] == "float32"
    assert not all(np.array_equal(x, y) for x, y in zip(a, b))  # half floats against float32
    ctx = _run(tiny_scene, tiny_exposures, run)
    assert ctx.times["export"]["cached"]
    rep = json.loads((run / "report.json").read_text())
    assert (rep["settings"]["export"]["half"] is True and rep["export"]["exr"] == "half"
            and rep["cache_keys"] == ctx.keys)
    again = [read_exr(p) for p in sorted((run / "hdr").glob("*.exr"))]
    assert len(again) == len(a) and all(np.array_equal(x, y) for x, y in zip(again, a))
    assert len(list((run / "previous").glob("*/hdr/frame_00000.exr"))) == 2  # A's first copy and B's


def test_flow_at_a_working_size_runs_end_to_end(tiny_scene, tiny_exposures, tmp_path, monkeypatch):
    """Large frames get their flow on smaller copies (scale.WORKING_SHORT_SIDE); the run trains on it."""
    from layercam.vision import scale

    monkeypatch.setattr(scale, "WORKING_SHORT_SIDE", 16)
    ctx = _run(tiny_scene, tiny_exposures, tmp_path / "run")
    assert ctx.results["flow"].summary["working_size"] == [16, 16] and ctx.flow.grid == (16, 16)
    rep = json.loads((tmp_path / "run" / "report.json").read_text())
    assert rep["train"]["final_loss"]["color"] < 0.5 * rep["train"]["first_loss"]["color"]


def test_masks_that_cover_as_much_elsewhere_are_other_input():
    """The stages' input key reads the masks' pixels: a corrected mask that covers as many pixels
    somewhere else is not the cached one (it was keyed on per-frame sums)."""
    from layercam.io.clip import fingerprint as masks_fingerprint  # what the stages' input key calls

    m = np.zeros((2, 8, 8), np.float32)
    m[:, 2:4, 2:4] = 1
    moved = np.roll(m, 3, axis=2)
    assert moved.sum(axis=(1, 2)).tolist() == m.sum(axis=(1, 2)).tolist()
    assert masks_fingerprint(moved) != masks_fingerprint(m) and masks_fingerprint(m.copy()) == masks_fingerprint(m)


def test_a_stage_key_hashes_the_resolved_settings_it_reads_and_nothing_else():
    """A stage's cache key is the hash of the resolved settings it reads (``Stage.reads``) with
    ``CACHE_VERSION``: the training's key changes with a loss or train setting, not with an export
    setting, nor with ``train.checkpoint_every`` (it cannot change a result)."""
    from types import SimpleNamespace

    from layercam.pipelines.runner import settings_read
    from layercam.pipelines.stages import TrainStage
    from layercam.engine.resolve import resolve

    def key(*sets):
        r = resolve(load_config("fast", ["model.layers=1", *sets]), frames=4, hw=(32, 32))
        return settings_read(SimpleNamespace(resolved=r, cfg=None, task="hdr-video"), TrainStage.reads)

    base = key()
    assert key("export.half=false") == base and key("train.checkpoint_every=7") == base
    assert key("loss.robust=0.05") != base and key("train.seed=3") != base and key("loss.alpha_flow_keep=0.5") != base
    assert base["static"] is False and "checkpoint_every" not in base["train"]


def test_a_stage_that_fills_the_disk_is_one_error_and_the_run_goes_on_after(tiny_scene, tiny_exposures, tmp_path):
    """A stage writing without ``atomic_write`` (``np.savez``, a folder of frames) that meets a full
    disk (``OSError`` ENOSPC) ends the run with one ``LayercamError`` naming the stage and its
    folder; the stages before it stay finished, and the same run without the failure is cached up
    to there."""
    import errno

    from layercam.core.errors import LayercamError
    from layercam.pipelines.runner import Stage

    class FullDisk(Stage):
        name, deps = "fulldisk", ("export",)

        def run(self, ctx, out):
            (out / "partial.npz").write_bytes(b"part")
            raise OSError(errno.ENOSPC, "No space left on device")

    run = tmp_path / "run"
    cfg = load_config("fast", TINY)
    with pytest.raises(LayercamError,
                       match=r"\[fulldisk\] cannot write in .*fulldisk-.*: No space left on "
                             r"device; free some space") as e:
        run_task("hdr-video", tiny_scene.clip, tiny_exposures, cfg, run, progress=False, extra_stages=[FullDisk()])
    assert "\n" not in str(e.value)
    assert len(list((run / "cache").glob("export-*/done.json"))) == 1
    ctx = _run(tiny_scene, tiny_exposures, run)
    assert all(ctx.times[k]["cached"] for k in ("flow", "bootstrap", "train", "export"))


@pytest.mark.parametrize("method", ["raft_small", "raft"])
def test_a_raft_flow_method_with_its_weights_file_runs_end_to_end(tiny_scene, tiny_exposures, tmp_path, method):
    """``flow.method=raft_small`` (or ``raft``: the variant the file holds) with a local weights
    file: the flow stage reads the file (it was passed validation, then called without it). A
    torchvision RAFT with random weights stands in for trained ones (none are downloaded)."""
    import torch
    from torchvision.models.optical_flow import raft_small

    weights = tmp_path / "raft_small.pth"
    torch.manual_seed(0)
    torch.save(raft_small(weights=None, progress=False).state_dict(), weights)
    ctx = _run(tiny_scene, tiny_exposures, tmp_path / "run", [f"flow.method={method}", f"flow.raft_weights={weights}"])
    assert ctx.results["flow"].pairs == tiny_scene.clip.T - 1 and np.isfinite(ctx.flow.fw).all()
    assert len(list((tmp_path / "run" / "hdr").glob("*.exr"))) == tiny_scene.clip.T
