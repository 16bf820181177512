"""Tests of layercam.io.exposure: exposure specs, alternating-phase detection, errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, strategies as st
from hypothesis.extra import numpy as hnp

from layercam.camera.exposure import EV_BOUND, ExposureField
from layercam.core.errors import LayercamError
from layercam.io import Clip, Exposures, load_clip, parse_exposures

from props import EV, _finite, props

from conftest import SHARED_DATA as DATA  # $LAYERCAM_DATA, else beside the checkout

needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"shared data folder {DATA} is absent")


def alt_clip(T: int = 8, ev: float = 3.0, odd_brighter: bool = True, n: int = 2, seed: int = 0) -> Clip:
    """Synthetic static scene with exposures cycling over n phases, gamma 2.2 encoded."""
    rng = np.random.default_rng(seed)
    radiance = np.exp(rng.uniform(np.log(0.01), np.log(0.4), size=(24, 32, 1))) * np.ones((1, 1, 3))
    frames = []
    for t in range(T):
        k = t % n
        stop = k if odd_brighter else (n - 1 - k)
        lin = radiance * 2.0 ** (ev * stop)
        frames.append(np.clip(lin, 0, 1) ** (1 / 2.2))
    return Clip(frames=np.stack(frames).astype(np.float32), source="synthetic:alt",
                names=[f"{t:05d}" for t in range(T)])


def plain_clip(T: int = 5, **kw) -> Clip:
    return Clip(frames=np.full((T, 4, 6, 3), 0.5, np.float32), source="x",
                names=[f"{t:05d}" for t in range(T)], **kw)


@pytest.mark.parametrize("odd_brighter", [True, False])
def test_alt_detects_brighter_phase(odd_brighter):
    clip = alt_clip(odd_brighter=odd_brighter)
    e = parse_exposures("alt", clip, ev_step=3)
    bright = 1 if odd_brighter else 0
    assert e.learn == "none" and e.count_distinct == 2
    np.testing.assert_allclose(e.log2_dt[bright::2], 3.0)
    np.testing.assert_allclose(e.log2_dt[1 - bright::2], 0.0)
    assert list(e.phase) == [t % 2 for t in range(clip.T)]
    assert ("odd" if odd_brighter else "even") in e.reason

    r = parse_exposures("alt", clip)
    assert r.learn == "ratio"
    assert r.log2_dt[bright] == pytest.approx(3.0, abs=0.3)  # measured initial ratio
    assert r.log2_dt.min() == 0


def test_alt_ratio_clamped():
    tiny = parse_exposures("alt", alt_clip(ev=0.05))
    assert tiny.log2_dt.max() == pytest.approx(0.5) and "warning" in tiny.reason


def test_alt3_sorted_by_brightness():
    clip = alt_clip(T=9, ev=2.0, odd_brighter=False, n=3)  # phase 0 brightest, phase 2 darkest
    e = parse_exposures("alt3", clip, ev_step=2)
    np.testing.assert_allclose(e.log2_dt[:3], [4.0, 2.0, 0.0])
    r = parse_exposures("alt3", clip)
    assert r.learn == "ratio" and r.count_distinct == 3
    np.testing.assert_allclose(r.log2_dt[:3], [4.0, 2.0, 0.0], atol=0.4)


@pytest.mark.parametrize("spec,n", [("alt3", 2), ("alt", 3)])
def test_a_wrong_exposure_count_is_one_line(spec, n):
    """A clip alternating over n exposures given the other cycle: its frames of the same phases
    differ by the whole step, refused with what to try instead."""
    with pytest.raises(LayercamError, match=f"do not repeat every {3 if n == 2 else 2} exposures.*try --exposures"):
        parse_exposures(spec, alt_clip(T=12, ev=2.0, n=n))
    parse_exposures("alt" if n == 2 else "alt3", alt_clip(T=12, ev=2.0, n=n))  # the right cycle passes


def test_alt_respects_stride():
    clip = alt_clip(T=6)
    clip.meta["frame_indices"] = [0, 3, 6, 9, 12, 15]  # stride 3 of an alternating source
    assert list(parse_exposures("alt", clip, 3).phase) == [0, 1, 0, 1, 0, 1]
    clip.meta["frame_indices"] = [0, 2, 4, 6, 8, 10]
    with pytest.raises(LayercamError, match="stride"):
        parse_exposures("alt", clip)


def test_cycle_none_and_learn():
    clip = plain_clip(5)
    e = parse_exposures("-2,0,2", clip)
    np.testing.assert_allclose(e.log2_dt, [0, 2, 4, 0, 2])
    assert e.learn == "none" and list(e.phase) == [0, 1, 2, 0, 1]
    with pytest.raises(LayercamError, match="has 6 entries for 5 frames"):
        parse_exposures("0,1,2,3,4,5", clip)
    for spec in (None, "none", "single"):
        s = parse_exposures(spec, clip)
        assert s.count_distinct == 1 and not s.log2_dt.any() and s.learn == "none"
    lrn = parse_exposures("learn", alt_clip(T=4))
    assert lrn.learn == "all" and lrn.log2_dt[0] == 0
    assert lrn.log2_dt[1] == pytest.approx(3.0, abs=0.3)
    assert isinstance(lrn, Exposures) and lrn.log2_dt.dtype == np.float32


def test_time_file_formats(tmp_path):
    clip = plain_clip(4)
    f = tmp_path / "times.txt"
    f.write_text("# exposure times\n0.01\n\n1/50  # comment\n0.04\n1/12.5\n")
    e = parse_exposures(str(f), clip)
    np.testing.assert_allclose(e.log2_dt, [0, 1, 2, 3], atol=1e-5)
    np.testing.assert_allclose(e.dt_seconds, [0.01, 0.02, 0.04, 0.08], rtol=1e-6)

    named = Clip(frames=np.zeros((2, 2, 2, 3), np.float32), source="x", names=["B", "A"])
    f2 = tmp_path / "image_list.txt"
    f2.write_text("# Filename exposure 1/shutter_speed\nA.png 2 0.5\nB.png 8 0.125\n")
    e2 = parse_exposures(str(f2), named)
    np.testing.assert_allclose(e2.log2_dt, [2, 0])


def test_time_file_subset_by_frame_index(tmp_path):
    clip = plain_clip(2)
    clip.meta.update(frame_indices=[0, 2], n_source_frames=4)
    f = tmp_path / "t.txt"
    f.write_text("1\n2\n4\n8\n")
    np.testing.assert_allclose(parse_exposures(str(f), clip).log2_dt, [0, 2])


@pytest.mark.parametrize(
    "content,match",
    [
        ("0.1\n0.2\n0.3\n0.4\n0.5\n", "lists 5 times for 6 frames"),
        ("", "no times"),
        ("# only a comment\n", "no times"),
        ("0.1\n0\n0.1\n0.1\n0.1\n0.1\n", "positive"),
        ("0.1\n-1\n0.1\n0.1\n0.1\n0.1\n", "positive"),
        ("a.png\n", "no exposure time"),
    ],
)
def test_time_file_errors(tmp_path, content, match):
    f = tmp_path / "t.txt"
    f.write_text(content)
    with pytest.raises(LayercamError, match=match):
        parse_exposures(str(f), plain_clip(6))


@pytest.mark.parametrize(
    "spec,kw,T,match",
    [
        ("bogus", {}, 4, "unknown exposure spec"),
        ("0,x", {}, 4, "not a number"),
        ("missing/times.txt", {}, 4, "not found"),
        ("alt", {}, 1, "at least 2"),
        ("alt3", {}, 2, "at least 3"),
        ("exif", {}, 3, "not a set of images"),
        ("alt", {"ev_step": -1}, 4, "positive"),
    ],
)
def test_spec_errors(spec, kw, T, match):
    with pytest.raises(LayercamError, match=match):
        parse_exposures(spec, plain_clip(T), **kw)


def test_exif_missing_names_frame():
    clip = plain_clip(3, exif_exposures=[0.1, None, 0.2])
    with pytest.raises(LayercamError, match="00001"):
        parse_exposures("exif", clip)
    ok = parse_exposures("exif", plain_clip(2, exif_exposures=[0.125, 1.0]))
    np.testing.assert_allclose(ok.log2_dt, [0, 3])


@pytest.mark.data
@needs_data
def test_exif_on_real_jpegs():
    clip = load_clip(DATA / "bracket_frobisher_exif", resize=0.1)
    e = parse_exposures("exif", clip)
    np.testing.assert_allclose(e.log2_dt, [0, 3, 6], atol=1e-5)
    assert e.count_distinct == 3


@pytest.mark.data
@needs_data
def test_taipei_image_list_and_real_alt_video():
    taipei = DATA / "bracket_taipei"
    clip = load_clip(taipei, resize=0.1, stride=3)
    e = parse_exposures(str(taipei / "image_list.txt"), clip)
    np.testing.assert_allclose(e.log2_dt, [9, 6, 3, 0], atol=1e-5)  # 32 s, 4 s, 0.5 s, 1/16 s

    video = load_clip(DATA / "altexp_video_basler" / "clip_2exp_3stop.mp4", max_frames=12)
    a = parse_exposures("alt", video)
    assert a.log2_dt[0] == 0 and a.log2_dt[1] > 1.5  # frame 0 is the low exposure


@props(40)
@given(
    log2=hnp.arrays(np.float32, st.integers(1, 6), elements=EV),
    learn=st.sampled_from(["none", "ratio", "all"]),
    delta=st.floats(-1e6, 1e6, width=32),
)
def test_exposures_bounded_finite_and_reference_fixed(log2, learn, delta):
    phase = np.arange(len(log2)) % 2
    ef = ExposureField(log2, learn, phase)
    if ef.delta is not None:
        with torch.no_grad():
            ef.delta.fill_(delta)
    v = ef.values()
    init = torch.from_numpy(log2)
    assert _finite(v)
    assert float((v - init).abs().max()) <= EV_BOUND + 1e-3
    assert float(v[0]) == pytest.approx(float(log2[0]), abs=1e-5)  # the reference frame / phase
    t = torch.arange(len(log2))
    assert ef(t).shape == (len(log2), 1)
