"""``layercam edit``: paint on the exported foreground atlas; the paint moves with the object."""

from __future__ import annotations

import json
import shutil

import numpy as np

from layercam.cli import main
from layercam.io import read_exr, read_video


def _paint_on_object(run, scene, out_png, colour=(0.1, 0.2, 1.0)):
    """Paints a disc of ``colour`` on the exported layer-1 atlas where the object's centre maps in frame 0."""
    import cv2

    from layercam.engine.checkpoint import load_run_model
    from layercam.scene.render import render_frame

    model, meta = load_run_model(run)
    hw = tuple(meta["frame_hw"])
    uv = render_frame(model, 0, hw, "uv")["uv"][1]
    cx, cy = np.round(scene.meta["object_centre"][0]).astype(int)
    u, v = uv[cy, cx]
    png = cv2.imread(str(run / "atlases" / "layer1.png"), cv2.IMREAD_UNCHANGED)
    res = png.shape[0]
    px, py = (u + 1) / 2 * res - 0.5, (v + 1) / 2 * res - 0.5
    rad = max(2.0, 0.12 * res)
    yy, xx = np.mgrid[0:res, 0:res]
    disc = (xx - px) ** 2 + (yy - py) ** 2 <= rad**2
    png[disc, :3] = np.round(np.array(colour[::-1]) * 255).astype(np.uint8)  # BGR
    png[disc, 3] = 255
    cv2.imwrite(str(out_png), png)
    return model, meta


def test_edit_moves_with_the_object(two_layer_run, tmp_path):
    scene, run = two_layer_run["scene"], two_layer_run["run"]
    T = scene.clip.T
    edited = tmp_path / "edited.png"
    _paint_on_object(run, scene, edited)
    out = tmp_path / "edit"
    assert main(["edit", str(run), "--layer", "1", "--atlas", str(edited), "--out", str(out), "--quiet"]) == 0
    assert (out / "edited.mp4").is_file() and (out / "preview.mp4").is_file()
    info = json.loads((out / "edit.json").read_text())
    assert info["unchanged_px_left_to_learned_atlas"] > 0  # painted on the exported PNG: the rest stays learned
    ldr, _ = read_video(out / "edited.mp4")
    assert len(ldr) == T
    import cv2

    c0, c1 = scene.meta["object_centre"][0], scene.meta["object_centre"][T - 1]
    assert np.hypot(*(c1 - c0)) > 10  # two distant frames: the object has moved well over its radius
    from layercam.engine.checkpoint import load_run_model
    from layercam.scene.render import render_frame

    model, _ = load_run_model(run)
    for t in (0, T - 1):
        # the model's own rendering (the run's hdr/ is corrected towards each frame, export.faithful;
        # an edit is a re-render of the model, and the frames would undo it)
        before = render_frame(model, t, ldr[t].shape[:2], ("hdr",))["hdr"]
        after = read_exr(out / "hdr" / f"frame_{t:05d}.exr")
        assert np.isfinite(after).all()
        changed = np.abs(np.log2(np.maximum(after, 1e-8)) - np.log2(np.maximum(before, 1e-8))).max(-1) > 0.2
        assert changed.sum() >= 6, f"frame {t}: the edit is not visible"
        ys, xs = np.nonzero(changed)
        cx, cy = scene.meta["object_centre"][t]
        assert np.hypot(xs.mean() - cx, ys.mean() - cy) < 0.6 * scene.meta["object_radius"], (t,
                        xs.mean(), ys.mean(), cx, cy)
        near_object = cv2.dilate(scene.fg_mask[t].astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
        assert near_object[changed].mean() > 0.95  # nothing lands on the background
        # in the camera's output the painted pixels are blue: the colour went through the camera
        px = ldr[t][changed].astype(np.float32)
        assert (px[:, 2] > px[:, 0] + 20).mean() > 0.8


def test_edit_refuses_overwrite_bad_layer_and_empty_edits(two_layer_run, tmp_path, capsys):
    run = two_layer_run["run"]
    edited = tmp_path / "edited.png"
    _paint_on_object(run, two_layer_run["scene"], edited)
    out = tmp_path / "edit"
    assert main(["edit", str(run), "--atlas", str(edited), "--out", str(out), "--quiet"]) == 0
    assert main(["edit", str(run), "--atlas", str(edited), "--out", str(out), "--quiet"]) == 2
    assert "already holds an edit" in capsys.readouterr().err
    assert main(["edit", str(run), "--atlas", str(edited), "--out", str(out), "--quiet", "--overwrite"]) == 0
    assert main(["edit", str(run), "--layer", "2", "--atlas", str(edited), "--out",
                 str(tmp_path / "e2"), "--quiet"]) == 2
    same = tmp_path / "same.png"
    shutil.copy(run / "atlases" / "layer1.png", same)
    assert main(["edit", str(run), "--atlas", str(same), "--out", str(tmp_path / "e3"), "--quiet"]) == 2
    assert "nothing to composite" in capsys.readouterr().err
    assert main(["edit", str(run), "--atlas", str(tmp_path / "missing.png"), "--out",
                 str(tmp_path / "e4"), "--quiet"]) == 2


def test_inverse_tone_round_trip(two_layer_run):
    from layercam.engine.checkpoint import load_run_model
    from layercam.scene.render import inverse_tone, tone_map_log2

    model, _ = load_run_model(two_layer_run["run"])
    rgb = np.random.default_rng(0).uniform(0.05, 0.95, (50, 3)).astype(np.float32)
    for log2_dt in (0.0, 1.5, 3.0):
        back = tone_map_log2(model, inverse_tone(model, rgb, log2_dt), log2_dt)
        assert np.abs(back - rgb).max() < 2e-3


def test_interrupted_edit_leaves_no_partial_edit_and_is_redone(two_layer_run, tmp_path, monkeypatch):
    """Ctrl-C half-way through an edit: nothing under the final names (no edit.json), nor its
    staging folder (the frames it had written are given back), and the same command then writes
    the whole edit (issue 18: an interrupted render is redone)."""
    run = two_layer_run["run"]
    edited = tmp_path / "edited.png"
    _paint_on_object(run, two_layer_run["scene"], edited)
    out = tmp_path / "edit"
    argv = ["edit", str(run), "--atlas", str(edited), "--out", str(out), "--quiet"]
    monkeypatch.setenv("LAYERCAM_SIGNAL_AT", "edit:3:INT")
    assert main(argv) == 130
    assert sorted(p.name for p in out.iterdir()) == []
    monkeypatch.delenv("LAYERCAM_SIGNAL_AT")
    assert main(argv) == 0
    assert sorted(p.name for p in out.iterdir()) == ["edit.json", "edited.mp4", "hdr", "preview.mp4"]
    assert len(list((out / "hdr").glob("*.exr"))) == two_layer_run["scene"].clip.T


def test_edit_of_a_faded_foreground_repeats_the_runs_warning(two_layer_run, tmp_path, capsys):
    """A run whose report says its foreground faded: editing layer 1 says it again (the edit shows
    only where alpha is left); editing the background does not, nor does a run without it."""
    from layercam.pipelines.stages import FADED

    run = tmp_path / "run"
    shutil.copytree(two_layer_run["run"], run)
    edited = tmp_path / "edited.png"
    _paint_on_object(run, two_layer_run["scene"], edited)
    assert main(["edit", str(run), "--atlas", str(edited), "--out", str(tmp_path / "e0"), "--quiet"]) == 0
    assert FADED not in capsys.readouterr().err  # the shared run did not fade
    rep = json.loads((run / "report.json").read_text())
    rep["warnings"] = rep["warnings"] + [f"{FADED}: its alpha holds 0.00% of the frames, the "
                                         "motion masks it started from 2.91%"]
    (run / "report.json").write_text(json.dumps(rep))
    assert main(["edit", str(run), "--atlas", str(edited), "--out", str(tmp_path / "e1"), "--quiet"]) == 0
    assert f"warning: {FADED}: its alpha holds 0.00%" in capsys.readouterr().err
    assert main(["edit", str(run), "--layer", "0", "--atlas", str(edited), "--out",
                 str(tmp_path / "e2"), "--quiet"]) == 0
    assert FADED not in capsys.readouterr().err

