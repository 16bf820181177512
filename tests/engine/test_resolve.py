"""The run's settings resolved once (layercam.engine.resolve): the static camera's consequences, the
step cap and its floor, and one resolution per run."""

from __future__ import annotations

from layercam.core.presets import load_config
from layercam.engine import resolve as resolve_module
from layercam.engine.resolve import FLOOR_GRID_LEVELS, min_samples, resolve

from conftest import TINY


def test_static_camera_holds_the_background_still():
    """A static camera (``Resolved.static``) holds the background layer still when there are two
    layers; a moving camera leaves it free; one layer keeps no residual warp instead."""
    two = load_config("fast", ["model.layers=2"])
    assert resolve(two, frames=24, hw=(64, 64), measures={"corner_shift_px": 0.2}).still_background
    assert not resolve(two, frames=24, hw=(64, 64), measures={"corner_shift_px": 3.0}).still_background
    one = resolve(load_config("fast", ["model.layers=1"]), frames=24, hw=(64, 64), measures={"corner_shift_px": 0.2})
    assert not one.still_background and not one.residual and one.blur_centre
    paper = resolve(load_config("paper", ["model.layers=1"]), frames=24, hw=(64, 64), measures={"corner_shift_px": 0.2})
    assert not paper.static  # the paper's identity bootstrap: nothing registered by the flow


def _cap(preset, sets, frames, hw):
    return resolve(load_config(preset, ["model.layers=1", "model.blur=off"] + list(sets)),
                   frames=frames, hw=hw).settings


def test_short_stack_trains_fewer_steps():
    """A 3-shot 256x256 stack: balanced's 2000 steps x 8192 capped to the floor (300 steps) and
    the floor's model (resolve.FLOOR) whatever the preset; a 48-frame clip keeps its steps;
    train.passes_per_frame=0 turns the cap off (paper's default); a larger stack is capped above
    the floor and keeps the preset's batch."""
    cfg = _cap("balanced", [], 3, (256, 256))
    assert (cfg.train.steps, cfg.train.bootstrap_steps, cfg.train.batch) == (300, 150, 4096)
    assert _cap("balanced", [], 48, (144, 256)).train.steps == 2000
    assert _cap("balanced", ["train.passes_per_frame=0"], 3, (256, 256)).train.steps == 2000
    # at the floor every preset trains the floor's model: quality's 8 levels and width 128, fast's 5 levels
    for p in ("fast", "balanced", "quality"):
        c = _cap(p, [], 3, (256, 256))
        assert (c.train.steps, c.train.batch, c.scene.grid_levels, c.scene.atlas_width) == (300, 4096, 6, 64)
    # above the floor the cap keeps the preset's batch and width, at most 6 grid levels
    big = _cap("quality", [], 3, (510, 768))
    assert (big.train.steps, big.train.batch, big.scene.grid_levels, big.scene.atlas_width) == (861,
            8192, FLOOR_GRID_LEVELS, 128)
    assert _cap("quality", [], 48, (144, 256)).scene.grid_levels == 8
    assert _cap("fast", [], 3, (510, 768)).scene.grid_levels == 5
    # with a blur generator the floor is min_samples() (fast's steps x batch) in the preset's own model and batch
    for p, want in (("fast", (600, 4096, 5)), ("balanced", (300, 8192, 6)), ("quality", (300, 8192, 6))):
        c = resolve(load_config(p, ["model.layers=1", "model.blur=on"]), frames=3, hw=(256, 256)).settings
        assert (c.train.steps, c.train.batch, c.scene.grid_levels) == want, p
    # the paper trains the paper's steps (no cap) unless the user caps it; capped, its positional
    # encoding keeps its own width and batch at the floor
    r = resolve(load_config("paper", ["model.layers=1", "model.blur=off"]), frames=3, hw=(256, 256))
    assert r.settings.train.steps == 150000 and "no cap" in r.reasons["train.steps"]
    paper = _cap("paper", ["train.passes_per_frame=4"], 3, (256, 256))
    assert (paper.train.steps, paper.train.batch, paper.scene.atlas_width) == (300, 30000, 512)
    # a smaller batch asked for is kept at the floor
    assert _cap("balanced", ["train.batch=1024"], 3, (64, 64)).train.batch == 1024


def test_the_blur_floor_is_the_fast_presets_samples():
    fast = load_config("fast").train
    assert min_samples() == fast.steps * fast.batch


def _count_resolve(monkeypatch) -> list:
    """Every call of :func:`resolve` (where it is defined and where the task imported it)."""
    from layercam.pipelines import tasks

    calls: list = []
    real = resolve_module.resolve

    def counted(*a, **k):
        calls.append(a[3] if len(a) > 3 else k.get("task"))
        return real(*a, **k)

    for mod in (resolve_module, tasks):
        monkeypatch.setattr(mod, "resolve", counted)
    return calls


def test_resolve_runs_once_per_run(tiny_scene, tiny_exposures, tmp_path, monkeypatch):
    """A run resolves its settings once, after the analysis: the estimates before it bound the cost
    without resolving (layercam.engine.estimate.bound), the one after it and every stage read
    ``ctx.resolved``. Run again (every stage cached), it resolves once again."""
    from layercam.pipelines.tasks import run_task

    calls = _count_resolve(monkeypatch)
    cfg = load_config("fast", TINY)
    ctx = run_task("hdr-video", tiny_scene.clip, tiny_exposures, cfg, tmp_path / "run", progress=False)
    assert calls == ["hdr-video"] and ctx.resolved.settings.train.steps == 60
    run_task("hdr-video", tiny_scene.clip, tiny_exposures, cfg, tmp_path / "run", progress=False)
    assert len(calls) == 2


def test_the_command_line_resolves_once(tiny_frames, tmp_path, monkeypatch):
    """``layercam hdr-video``: the estimate from the input's header (before decoding), the one before
    the stages and the one after the analysis resolve nothing; the run resolves once."""
    from layercam.cli import main

    from conftest import tiny_argv

    calls = _count_resolve(monkeypatch)
    assert main(tiny_argv("hdr-video", tiny_frames, tmp_path / "run", "--exposures", "alt", "--ev-step", "3")) == 0
    assert calls == ["hdr-video"]
