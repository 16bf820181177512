"""The reliability corpus: bad input of every kind, as a user would type it, against the README's
promise: one ``error:`` line, exit code 2, no traceback, nothing finished changed and no folder
left behind. (Interrupted runs: tests/test_interruption.py; the run folder's lock: test_lock.py.)

Every case runs the real command line in this process (``layercam.cli.main``) next to one finished
run; ``{run}`` is that run's folder (whose files must not change), ``{fresh}`` a folder that must not
be created."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from layercam.cli import main

from conftest import TINY, tiny_argv

SETTINGS = [a for s in TINY for a in ("--set", s)]

# (id, argv template, a word the error line must hold)
CORPUS = [
    # input
    ("missing-file", ["hdr-video", "{tmp}/nope.mp4", "--out", "{fresh}"], "nope.mp4"),
    ("missing-folder", ["hdr-video", "{tmp}/nope/", "--out", "{fresh}"], "nope"),
    ("corrupt-video", ["hdr-video", "{corrupt}", "--out", "{fresh}"], "corrupt"),
    ("empty-folder", ["hdr-video", "{empty}", "--out", "{fresh}"], "empty"),
    ("mixed-sizes", ["hdr-video", "{mixed}", "--out", "{fresh}"], "--resize"),
    ("bad-resize", ["hdr-video", "{video}", "--resize", "0", "--out", "{fresh}"], "resize"),
    ("bad-resize-text", ["hdr-video", "{video}", "--resize", "axb", "--out", "{fresh}"], "resize"),
    ("max-frames-0", ["hdr-video", "{video}", "--max-frames", "0", "--out", "{fresh}"], "--max-frames"),
    ("stride-negative", ["hdr-video", "{video}", "--stride", "-2", "--out", "{fresh}"], "--stride"),
    ("masks-missing", ["hdr-video", "{video}", "--masks", "{tmp}/nomasks", "--out", "{fresh}"], "mask"),
    # exposures
    ("exposure-cycle-not-number", ["hdr-video", "{video}", "--exposures", "0,3,x", "--out", "{fresh}"], "exposure"),
    ("exposure-cycle-too-long",
     ["hdr-video", "{video}", "--exposures", "0,1,2,3,4,5", "--out", "{fresh}"], "6 entries"),
    ("exposure-count-wrong", ["hdr-video", "{video}", "--exposures", "{times3}", "--out", "{fresh}"], "3"),
    ("exposure-file-garbage", ["hdr-video", "{video}", "--exposures", "{garbage}", "--out", "{fresh}"], "garbage"),
    ("exposure-exif-on-video", ["hdr-video", "{video}", "--exposures", "exif", "--out", "{fresh}"], "exif"),
    ("exposure-unknown", ["hdr-video", "{video}", "--exposures", "sometimes", "--out", "{fresh}"], "sometimes"),
    ("ev-step-negative", ["hdr-video", "{video}", "--ev-step", "-3", "--out", "{fresh}"], "--ev-step"),
    ("ev-step-nan", ["hdr-video", "{video}", "--ev-step", "nan", "--out", "{fresh}"], "--ev-step"),
    ("ev-step-100", ["hdr-video", "{frames}", "--ev-step", "100", "--out", "{run}"],
     "--force-ev-step"),  # issue 18 item 8
    ("ev-step-without-alt",
     ["hdr-video", "{video}", "--exposures", "none", "--ev-step", "3", "--out", "{fresh}"], "alt"),
    # output
    ("out-under-proc", ["hdr-video", "{video}", "--out", "/proc/layercam-run"], "/proc/layercam-run"),
    ("out-is-a-file", ["hdr-video", "{video}", "--out", "{file}"], "is a file"),
    # settings
    ("set-unknown-key", ["hdr-video", "{video}", "--set", "train.stepz=3", "--out", "{fresh}"], "stepz"),
    ("set-unknown-section", ["hdr-video", "{video}", "--set", "trian.steps=3", "--out", "{fresh}"], "trian"),
    ("set-no-equals", ["hdr-video", "{video}", "--set", "train.steps", "--out", "{fresh}"], "key=value"),
    ("set-not-a-number", ["hdr-video", "{video}", "--set", "train.steps=many", "--out", "{fresh}"], "many"),
    # a bad training setting on a clip that would otherwise run: items 5 and 6
    *((name, ["hdr-video", "{frames}", "--ev-step", "3", "--set", setting, "--out", "{run}"],
       setting.split("=")[0])
      for name, setting in (("steps-negative", "train.steps=-5"), ("lr-negative", "train.lr=-1"),
                            ("lr-huge", "train.lr=1e6"), ("batch-0", "train.batch=0"))),
    ("lr-nan", ["hdr-video", "{video}", "--set", "train.lr=nan", "--out", "{fresh}"], "train.lr"),  # item 7
    ("lr-inf", ["hdr-video", "{video}", "--set", "train.lr=inf", "--out", "{fresh}"], "train.lr"),  # item 7
    ("grid-lr-negative", ["hdr-video", "{video}", "--set", "train.grid_lr=-0.1", "--out", "{fresh}"], "train.grid_lr"),
    ("set-bad-choice", ["hdr-video", "{video}", "--set", "train.autocast=bogus", "--out", "{fresh}"], "bogus"),
    ("set-offset-negative",
     ["deblur-video", "{video}", "--set", "blur.max_offset=-1", "--out", "{fresh}"],
     "blur.max_offset"),
    ("set-alpha-flow-keep-above-one",
     ["hdr-video", "{video}", "--set", "loss.alpha_flow_keep=5", "--out", "{fresh}"],
     "loss.alpha_flow_keep"),
    ("set-layers-3", ["hdr-video", "{video}", "--set", "model.layers=3", "--out", "{fresh}"], "model.layers"),
    ("nits-white-0", ["hdr-video", "{video}", "--nits-white", "0", "--out", "{fresh}"], "--nits-white"),  # issue 41
    ("nits-white-negative", ["hdr-video", "{video}", "--nits-white", "-5", "--out", "{fresh}"], "--nits-white"),
    ("nits-white-nan", ["hdr-video", "{video}", "--nits-white", "nan", "--out", "{fresh}"], "--nits-white"),
    ("nits-white-above-peak", ["hdr-video", "{video}", "--nits-white", "5000", "--out", "{fresh}"], "--nits-white"),
    ("hdr-format-unknown", ["hdr-video", "{video}", "--hdr-format", "dolby", "--out", "{fresh}"], "--hdr-format"),
    ("set-nits-white-0",
     ["hdr-video", "{video}", "--set", "export.nits_white=0", "--out", "{fresh}"],
     "export.nits_white"),
    ("set-hdr-format-unknown",
     ["hdr-video", "{video}", "--set", "export.hdr_format=hdr10", "--out", "{fresh}"],
     "export.hdr_format"),
    ("preset-unknown", ["hdr-video", "{video}", "--preset", "ludicrous", "--out", "{fresh}"], "ludicrous"),
    ("preset-broken-toml", ["hdr-video", "{video}", "--preset", "{badtoml}", "--out", "{fresh}"], "preset"),
    ("steps-0", ["hdr-video", "{video}", "--steps", "0", "--out", "{fresh}"], "--steps"),
    ("nproc-0", ["hdr-video", "{video}", "--nproc", "0", "--out", "{fresh}"], "--nproc"),
    ("unknown-option", ["hdr-video", "{video}", "--colour", "red", "--out", "{fresh}"], "--colour"),
    ("bad-choice", ["hdr-video", "{video}", "--blur", "7x7", "--out", "{fresh}"], "--blur"),
    ("max-offset-negative", ["deblur-video", "{video}", "--max-offset", "-5", "--out", "{fresh}"],
     "--max-offset"),  # item 9
    ("max-offset-nan", ["deblur-video", "{video}", "--max-offset", "nan", "--out", "{fresh}"],
     "--max-offset"),  # item 9
    ("deblur-one-frame", ["deblur-video", "{video}", "--max-frames", "1", "--out", "{fresh}"], "2 frames"),
    # fuse-stack
    ("fuse-one-image", ["fuse-stack", "{frames}/frame_000.png", "--out", "{fresh}"], "2 images"),
    ("fuse-ev-list-short", ["fuse-stack", "{frames}", "--exposures", "0,2", "--out", "{fresh}"],
     "one per image"),  # a stack has no EV cycle
    ("fuse-bad-reference", ["fuse-stack", "{frames}", "--reference", "7", "--out", "{fresh}"], "reference"),
    # render
    ("render-nothing", ["render", "{run}"], "nothing to render"),
    ("render-fps-negative", ["render", "{run}", "--exposure", "1", "--fps", "-5"], "--fps"),  # item 10
    ("render-fps-nan", ["render", "{run}", "--exposure", "1", "--fps", "nan"], "--fps"),
    ("render-exposure-99", ["render", "{run}", "--exposure", "99"], "--exposure"),
    ("render-exposure-inf", ["render", "{run}", "--exposure", "inf"], "--exposure"),
    ("render-focus-without-blur", ["render", "{run}", "--focus", "0.5"], "blur"),
    ("render-frame-out-of-range", ["render", "{run}", "--sweep", "exposure", "--frame", "9"], "--frame"),
    ("render-steps-1", ["render", "{run}", "--sweep", "exposure", "--steps", "1"], "--steps"),
    ("render-range-text", ["render", "{run}", "--sweep", "exposure", "--range", "0,x"], "range"),
    ("render-not-a-run", ["render", "{tmp}", "--exposure", "1"], "checkpoint.pt"),
    ("render-exists", ["render", "{run}", "--exposure", "0"], "--overwrite"),
    ("render-hdr-format-unknown", ["render", "{run}", "--hdr-format", "none"], "--hdr-format"),
    ("render-nits-white-alone", ["render", "{run}", "--nits-white", "300"], "--hdr-format"),
    ("render-nits-white-nan", ["render", "{run}", "--hdr-format", "hlg", "--nits-white", "nan"], "--nits-white"),
    # edit
    ("edit-fps-negative",
     ["edit", "{run}", "--layer", "0", "--atlas", "{atlas}", "--fps", "-5", "--out", "{fresh}"],
     "--fps"),  # item 10
    ("edit-out-is-a-file",
     ["edit", "{run}", "--layer", "0", "--atlas", "{atlas}", "--out", "{file}"], "is a file"),
    # item 10
    ("edit-out-under-proc",
     ["edit", "{run}", "--layer", "0", "--atlas", "{atlas}", "--out", "/proc/layercam-edit"],
     "/proc/layercam-edit"),  # item 10
    ("edit-layer-missing", ["edit", "{run}", "--layer", "1", "--atlas", "{atlas}", "--out", "{fresh}"], "--layer"),
    ("edit-atlas-missing",
     ["edit", "{run}", "--layer", "0", "--atlas", "{tmp}/none.png", "--out", "{fresh}"],
     "none.png"),
    ("edit-atlas-unchanged",
     ["edit", "{run}", "--layer", "0", "--atlas", "{same}", "--out", "{fresh}"],
     "nothing to composite"),
    # batch
    ("batch-missing-manifest", ["batch", "{tmp}/jobs.csv"], "jobs.csv"),
    ("batch-summary-is-a-folder", ["batch", "{manifest}", "--summary", "{tmp}"], "--summary"),  # item 11
    ("batch-summary-under-proc",
     ["batch", "{manifest}", "--summary", "/proc/layercam/summary.json"], "/proc/layercam"),
    # item 11
    # numbers out of range, sizes that cannot fit (issue 42): refused before any work
    ("resize-huge", ["hdr-video", "{video}", "--resize", "100000x100000", "--out", "{fresh}"], "--resize"),
    ("batch-huge", ["hdr-video", "{video}", "--set", "train.batch=1e12", "--out", "{fresh}"], "train.batch"),
    ("atlas-width-huge",
     ["hdr-video", "{video}", "--set", "scene.atlas_width=1000000000", "--out", "{fresh}"],
     "scene.atlas_width"),
    ("grid-features-huge",
     ["hdr-video", "{video}", "--set", "scene.grid_features=1000000000", "--out", "{fresh}"],
     "scene.grid_features"),
    ("deblur-resize-huge", ["deblur-video", "{video}", "--resize", "100000x100000", "--out", "{fresh}"], "--resize"),
    ("fuse-resize-huge", ["fuse-stack", "{frames}", "--resize", "100000x100000", "--out", "{fresh}"], "--resize"),
    ("seed-huge", ["hdr-video", "{video}", "--set", "train.seed=1e30", "--out", "{fresh}"], "train.seed"),
    ("exposure-time-huge", ["hdr-video", "{video}", "--exposures", "{times_huge}", "--out", "{fresh}"], "1e400/1"),
    ("exposure-time-tiny", ["hdr-video", "{video}", "--exposures", "{times_tiny}", "--out", "{fresh}"], "1/1e400"),
    ("exposure-cycle-huge", ["hdr-video", "{video}", "--exposures", "0,1e300", "--out", "{fresh}"], "1e300"),
    ("preset-binary", ["hdr-video", "{video}", "--preset", "{binary_toml}", "--out", "{fresh}"], "preset"),
    ("preset-folder", ["hdr-video", "{video}", "--preset", "{folder_toml}", "--out", "{fresh}"], "preset"),
    # demo
    ("demo-frames-0", ["demo", "--frames", "0", "--out", "{fresh}"], "--frames"),
    ("demo-ev-step-inf", ["demo", "--ev-step", "inf", "--out", "{fresh}"], "--ev-step"),
]


@pytest.fixture(scope="module")
def corpus(tmp_path_factory, tiny_frames):
    """One finished run (from RGBA frames: their alpha is dropped, said once) and the bad inputs."""
    import cv2

    from layercam.io import write_png, write_video

    tmp = tmp_path_factory.mktemp("corpus")
    frames = tmp / "rgba"
    frames.mkdir()
    imgs = sorted(tiny_frames.glob("*.png"))
    for p in imgs:
        bgr = cv2.imread(str(p))
        alpha = np.full(bgr.shape[:2], 255, np.uint8)
        alpha[:4, :4] = 0
        cv2.imwrite(str(frames / p.name), np.dstack([bgr, alpha]))
    run = tmp / "run"
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "layercam",
                        *tiny_argv("hdr-video", frames, run, "--ev-step", "3")],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    assert main(["render", str(run), "--exposure", "0", "--quiet"]) == 0
    paths = {"tmp": tmp, "run": run, "frames": frames, "rgba_stderr": r.stderr}
    video = tmp / "v.mp4"
    write_video(video, np.random.default_rng(0).random((4, 16, 16, 3)).astype(np.float32), fps=4)
    (tmp / "corrupt.mp4").write_bytes(b"\x00not a video" * 50)
    (tmp / "empty").mkdir()
    (tmp / "mixed").mkdir()
    write_png(tmp / "mixed" / "a.png", np.zeros((8, 8, 3), np.float32))
    write_png(tmp / "mixed" / "b.png", np.zeros((8, 10, 3), np.float32))
    (tmp / "times3.txt").write_text("0.01\n0.02\n0.04\n")
    (tmp / "garbage.txt").write_text("garbage\n1/x\n")
    (tmp / "broken.toml").write_text("[train\nsteps = 3\n")
    (tmp / "file").write_text("a regular file\n")
    (tmp / "times_huge.txt").write_text("1e400/1\n1/100\n1/100\n1/100\n")
    (tmp / "times_tiny.txt").write_text("1/100\n1/1e400\n1/100\n1/100\n")
    (tmp / "binary.toml").write_bytes(bytes(range(256)) * 8)
    (tmp / "folder.toml").mkdir()
    (tmp / "same.png").write_bytes((run / "atlases" / "layer0.png").read_bytes())
    painted = cv2.imread(str(run / "atlases" / "layer0.png"), cv2.IMREAD_UNCHANGED)
    painted[:8, :8] = (255, 0, 0, 255)
    cv2.imwrite(str(tmp / "atlas.png"), painted)
    (tmp / "manifest.csv").write_text(f"hdr-video,{video},{tmp / 'batch_out'},--preset fast\n")
    paths.update(video=video, corrupt=tmp / "corrupt.mp4", empty=tmp / "empty", mixed=tmp / "mixed",
                 times3=tmp / "times3.txt",
                 garbage=tmp / "garbage.txt", badtoml=tmp / "broken.toml",
                 times_huge=tmp / "times_huge.txt", times_tiny=tmp / "times_tiny.txt",
                 binary_toml=tmp / "binary.toml", folder_toml=tmp / "folder.toml",
                 file=tmp / "file", atlas=tmp / "atlas.png", same=tmp / "same.png",
                 manifest=tmp / "manifest.csv")
    return paths


def _snapshot(folder) -> dict:
    return {str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("case, argv, needle", CORPUS, ids=[c[0] for c in CORPUS])
def test_bad_input_is_one_line_and_changes_nothing(corpus, tmp_path, capsys, case, argv, needle):
    fresh = tmp_path / "fresh"
    argv = [a.format(fresh=fresh, **corpus) for a in argv]
    if argv[0] in ("hdr-video", "deblur-video", "fuse-stack", "demo"):
        own = {a.split("=")[0] for a in argv if "=" in a}  # a setting the case sets is not overridden by the tiny ones
        argv += ["--quiet", *(["--preset", "fast"] if "--preset" not in argv else []),
                 *[a for s in TINY if s.split("=")[0] not in own for a in ("--set", s)]]
    before = _snapshot(corpus["run"])
    code = main(argv)
    out, err = capsys.readouterr()
    assert code == 2, (code, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in out + err
    assert needle in lines[0], lines[0]
    assert _snapshot(corpus["run"]) == before, "a finished output changed"
    assert not fresh.exists(), "a folder was left behind"
    assert not (corpus["tmp"] / "batch_out").exists(), "a batch job ran"


def test_rgba_frames_say_once_that_alpha_is_dropped(corpus):
    """Issue 18 item 12: RGBA frames (alpha dropped) are said once, in the report too."""
    lines = [l for l in corpus["rgba_stderr"].splitlines() if "alpha" in l]
    assert len(lines) == 1, corpus["rgba_stderr"]
    assert lines[0].startswith("warning: 4 of 4 frames have an alpha channel"), corpus["rgba_stderr"]
    assert "2% of the pixels transparent" in lines[0]
    rep = json.loads((corpus["run"] / "report.json").read_text())
    assert rep["warnings"] == [lines[0].removeprefix("warning: ")]


def test_corpus_size():
    assert len(CORPUS) >= 50 and len({c[0] for c in CORPUS}) == len(CORPUS)


def test_ev_step_against_the_frames(tiny_frames):
    """Issue 18 item 8: the frames measure about 3 EV between neighbours. A step within 2 EV is
    silent; further but within a factor of 2 is said; beyond that refused unless forced."""
    from layercam.core.errors import LayercamError
    from layercam.io import load_clip, parse_exposures

    clip = load_clip(tiny_frames)
    assert parse_exposures("alt", clip, 4).warnings == []
    warned = parse_exposures("alt", clip, 5.5)
    assert len(warned.warnings) == 1 and "using 5.5" in warned.warnings[0] and "warning" in warned.reason
    for bad in (100, 12, 0.5):
        with pytest.raises(LayercamError, match="--force-ev-step"):
            parse_exposures("alt", clip, bad)
    forced = parse_exposures("alt", clip, 100, force_ev_step=True)
    assert forced.warnings and np.ptp(forced.log2_dt) == 100


@pytest.mark.parametrize("text",
                         ['{"key": "x"', "[]", "{}", "null", '{"key": 5, "names": 3}', '"abc"',
                          '{"key": "../x", "names": []}'])
def test_a_corrupt_outputs_json_is_refused_before_any_stage(corpus, tmp_path, capsys, text):
    """A run folder whose outputs.json is not what layercam writes: one line, exit 2, before any
    stage runs (once it was found only when publishing, after training), and nothing written."""
    import shutil

    run = tmp_path / "run"
    shutil.copytree(corpus["run"], run)
    (run / "outputs.json").write_text(text)
    before = _snapshot(run)
    code = main(["hdr-video", str(corpus["frames"]), "--ev-step", "3", "--out", str(run), "--quiet",
                 "--preset", "fast", *SETTINGS, "--set", "train.seed=7"])
    err = [ln for ln in capsys.readouterr().err.strip().splitlines()
           if not ln.startswith("warning: ")]  # the RGBA frames' note
    assert code == 2 and len(err) == 1 and err[0].startswith("error: ") and "outputs.json" in err[0], err
    assert _snapshot(run) == before
