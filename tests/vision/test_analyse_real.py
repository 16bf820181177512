"""The analysis on real captures of ../shared/data: static brackets, a Lytro focus pair, a moving person."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from layercam.engine import decide
from layercam.vision import analyse
from layercam.core.presets import load_config

from test_analyse import _flow, _single


def _real(paths, exposures, resize=None):
    from layercam.io import load_clip, parse_exposures

    clip = load_clip([str(p) for p in paths] if isinstance(paths, list) else str(paths), resize=resize)
    ex = parse_exposures(exposures, clip)
    fl = _flow(clip.frames, "dis_medium")
    m = analyse.measure(clip, ex, fl)
    cfg, reasons = decide.decide(load_config("balanced"), clip, ex, "fuse-stack", m)
    return SimpleNamespace(**decide.model_summary(cfg), reasons=reasons, homs=fl["homs"], hw=clip.frames.shape[1:3]), m


@pytest.mark.data
def test_real_static_brackets_are_one_sharp_layer(shared_data, tmp_path):
    """A registered, static 3-shot bracket (bracket_taipei 16 s / 2 s / 1/4 s; the frobisher JPEGs
    with EXIF) is one layer without a blur generator, and its homographies move no corner by the
    static threshold (the bootstrap then registers it by the identity, no residual warp)."""
    from layercam.core.geometry import chain_homographies, max_corner_shift
    from layercam.core.geometry import STATIC_CORNER_PX

    d = shared_data / "bracket_taipei"
    times = dict(line.split()[:2] for line in (d / "image_list.txt").read_text().splitlines()
                 if line.strip() and not line.startswith("#"))
    names = sorted(times)
    sub = [names[i] for i in (1, 4, 7)]
    (tmp_path / "t.txt").write_text("".join(f"{n} {times[n]}\n" for n in sub))
    cases = [([d / n for n in sub], str(tmp_path / "t.txt")),
             (sorted((shared_data / "bracket_frobisher_exif").glob("*.jpg")), "exif")]
    for paths, exposures in cases:
        spec, m = _real(paths, exposures)
        assert spec.layers == 1 and spec.blur == "off", (paths[0].parent.name, m, spec.reasons)
        assert max_corner_shift(chain_homographies(spec.homs, 1), *spec.hw) < STATIC_CORNER_PX


@pytest.mark.data
def test_real_focus_pair_gets_a_blur_generator(shared_data):
    """A Lytro near/far focus pair: focus differs by region, so the blur generator is chosen."""
    d = shared_data / "focus_pairs_lytro" / "color"
    spec, m = _real([d / "c_01_1.tif", d / "c_01_2.tif"], "none", resize="0.5")
    assert spec.blur != "off" and spec.layers == 1, (m, spec.reasons)


@pytest.mark.data
def test_real_moving_person_keeps_two_layers(shared_data):
    """DAVIS parkour (a running person, camera panning): two layers."""
    from layercam.io import load_clip

    clip = load_clip(str(shared_data / "layers_davis_parkour" / "frames"), resize="0.33", max_frames=12)
    ex = _single(clip.T)
    m = analyse.measure(clip, ex, _flow(clip.frames, "dis_medium"))
    cfg, reasons = decide.decide(load_config("balanced"), clip, ex, "hdr-video", m)
    assert cfg.model.layers == 2 and cfg.model.blur == "off", (m, reasons)
