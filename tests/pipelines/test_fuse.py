"""``layercam fuse-stack`` end to end on tiny synthetic stacks: outputs, tone-mapper choice, errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from layercam.cli import main
from layercam.io import read_exr, read_image, write_png

from conftest import SMALL_BLUR, TINY

def _argv(images, out, *extra):
    argv = ["fuse-stack", *map(str, images), "--out", str(out), "--preset", "fast", "--quiet", *extra]
    for s in TINY + SMALL_BLUR:
        argv += ["--set", s]
    return argv


def _write_stack(folder, frames, names):
    folder.mkdir()
    paths = [folder / f"{n}.png" for n in names]
    for p, f in zip(paths, frames):
        write_png(p, f)
    return paths


def test_mf_pair_fixed_tone_unaligned(tmp_path):
    """A two-image multi-focus pair, the second shifted by 2 px: fixed sRGB tone, all outputs. The
    blur generator is forced: 24 px frames are too small for the analysis to compare sharpness."""
    from layercam import synth

    sc = synth.mfme_stack(size=(24, 24), focus_settings=2, exposures_ev=(0.0,), planes=2, seed=3)
    frames = sc.clip.frames.copy()
    frames[1] = np.roll(frames[1], 2, axis=1)
    paths = _write_stack(tmp_path / "in", frames, ["near", "far"])
    run = tmp_path / "run"
    assert main(_argv(paths, run, "--reference", "first", "--blur", "3x3")) == 0
    hdr = read_exr(run / "fused.exr")
    png = read_image(run / "fused.png")
    assert hdr.shape == png.shape == (24, 24, 3)
    assert np.isfinite(hdr).all() and (hdr > 0).all()
    for name in ["crf.json", "crf.png", "psf.json", "checkpoint.pt", "report.json"]:
        assert (run / name).is_file(), name
    rep = json.loads((run / "report.json").read_text())
    assert rep["task"] == "fuse-stack"
    assert rep["analysis"]["tone_mapper"] == "fixed" and rep["analysis"]["blur"] == "3x3"
    assert rep["export"]["reference"] == 0
    # one exposure: fused.png is in the input's tonality, close to the inputs in brightness
    assert abs(float(png.mean()) - float(frames[0].mean())) < 0.08
    psf = json.loads((run / "psf.json").read_text())
    assert len(psf["spread_px"]) == 2 and all(np.isfinite(psf["spread_px"]))


def test_mfme_with_times_file_learns_tone_and_scores(tmp_path):
    """Three images, one per focus, each at another exposure (the paper's 3-image setting), times
    from a file: learned tone mapper, Reinhard PNG; then the scoring stage used by the benchmarks
    (fused HDR against the all-in-focus ground truth, next to the two-stage baseline) runs on the
    same run folder, reusing every cached stage."""
    from layercam import synth
    from layercam.core.presets import load_config
    from layercam.io import Exposures
    from layercam.io.clip import Clip
    from layercam.bench.evaluate import EvaluateStage
    from layercam.pipelines.tasks import run_task

    sc = synth.mfme_stack(size=(24, 24), focus_settings=3, exposures_ev=(0.0, 2.0, 4.0), planes=3, seed=1)
    idx = [0, 4, 8]
    names = [sc.clip.names[i] for i in idx]
    paths = _write_stack(tmp_path / "in", sc.clip.frames[idx], names)
    times = tmp_path / "times.txt"
    times.write_text("".join(f"{n}.png {sc.exposure_times[i]:g}\n" for n, i in zip(names, idx)))
    run = tmp_path / "run"
    assert main(_argv(paths, run, "--exposures", str(times))) == 0
    rep = json.loads((run / "report.json").read_text())
    assert rep["analysis"]["tone_mapper"] == "learned"
    assert rep["export"]["reference"] == 1  # the middle image
    assert rep["export"]["png"].startswith("Reinhard")
    hdr = read_exr(run / "fused.exr")
    assert np.isfinite(hdr).all() and hdr.max() / max(np.percentile(hdr, 5), 1e-9) > 4  # a real dynamic range
    assert json.loads((run / "crf.json").read_text())["kind"] == "learned"

    ev = sc.meta["ev"][idx]
    clip = Clip(sc.clip.frames[idx], "synthetic:mfme_stack", names)
    e = Exposures(ev - ev.min(), "none", None, "times", "test: known")
    ev_stage = EvaluateStage(sc, focus_index=sc.meta["focus_index"][idx], times=sc.exposure_times[idx])
    ctx = run_task("fuse-stack", clip, e, load_config("fast", TINY + SMALL_BLUR), run,
                   progress=False, extra_stages=[ev_stage])
    assert all(ctx.times[k]["cached"] for k in ("flow", "bootstrap", "train", "export"))
    res = ctx.results["evaluate"]
    assert 10 < res.metrics["psnr_mu"] < 100
    (name,) = res.baselines
    assert "two_stage_mfme" in name and np.isfinite(res.baselines[name]["psnr_mu"])
    assert json.loads((run / "report.json").read_text())["metrics"]["psnr_mu"] == res.metrics["psnr_mu"]


@pytest.mark.parametrize("extra, needle",
                         [(["--reference", "7"], "reference"),
                          (["--reference", "side"], "reference"),
                          (["--exposures", "nope.txt"], "nope.txt")])
def test_bad_arguments_fail_before_training(tmp_path, capsys, extra, needle):
    rng = np.random.default_rng(0)
    paths = _write_stack(tmp_path / "in", rng.random((2, 16, 16, 3)).astype(np.float32), ["a", "b"])
    run = tmp_path / "run"
    assert main(_argv(paths, run, *extra)) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "\n" not in err and needle in err
    assert not list(run.glob("cache/train-*"))


def test_single_image_is_refused(tmp_path, capsys):
    paths = _write_stack(tmp_path / "in", np.full((1, 16, 16, 3), 0.5, np.float32), ["a"])
    assert main(_argv(paths, tmp_path / "run")) == 2
    assert "at least 2" in capsys.readouterr().err


def test_an_interrupted_exposure_stack_resumes_to_the_uninterrupted_result(tmp_path, monkeypatch):
    """Ctrl-C in the middle of a bracket's training, then the same command: the fused EXR is the
    one a run that was never interrupted writes (bit for bit). The video path has its own tests
    (test_interruption.py); this one covers the stack's one-layer, learned-tone path. (Its tone
    curve stays monotone, so it passed with the global-RNG probe too: the model test
    ``test_loss_terms_do_not_read_the_global_rng`` is the one that catches that.)"""
    from layercam import synth

    sc = synth.mfme_stack(size=(24, 24), focus_settings=1, exposures_ev=(0.0, 2.0, 4.0), planes=2, seed=2)
    paths = _write_stack(tmp_path / "in", sc.clip.frames, sc.clip.names)
    times = tmp_path / "times.txt"
    times.write_text("".join(f"{n}.png {t:g}\n" for n, t in zip(sc.clip.names, sc.exposure_times)))
    argv = lambda run: _argv(paths, run, "--exposures", str(times), "--blur", "off")  # noqa: E731
    assert main(argv(tmp_path / "ref")) == 0
    monkeypatch.setenv("LAYERCAM_SIGNAL_AT", "train:30:INT")
    assert main(argv(tmp_path / "run")) == 130
    monkeypatch.delenv("LAYERCAM_SIGNAL_AT")
    assert main(argv(tmp_path / "run")) == 0
    rep = json.loads((tmp_path / "run" / "report.json").read_text())
    assert rep["train"]["resumed_from"] == 30
    assert np.array_equal(read_exr(tmp_path / "run" / "fused.exr"), read_exr(tmp_path / "ref" / "fused.exr"))
