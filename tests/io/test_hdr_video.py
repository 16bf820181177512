"""hdr.mp4 (issue 41): HEVC Main 10 with BT.2020 and PQ / HLG signalling and HDR metadata, that
decodes back to the EXRs' radiance; and the input's sound and frame rate kept in every video.

Real encodes and decodes through the bundled ffmpeg (which has no ffprobe: the stream properties are
read from ``ffmpeg -i`` and the first frame's side data, :func:`layercam.io.hdr_video_read.probe_video`).
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from layercam.cli import main
from layercam.io import read_exr, write_video
from layercam.io.hdr_video_read import probe_video, read_hdr_video
from layercam.io.ffmpeg import ffmpeg_exe

from conftest import TINY

FPS = 8
TONE = 440.0


def _argv(command: str, inp, out, *extra: str) -> list[str]:
    argv = [command, str(inp), "--out", str(out), "--preset", "fast", "--quiet", *extra]
    for s in TINY:
        argv += ["--set", s]
    return argv


def _sound(path: Path) -> np.ndarray:
    """The first audio stream of ``path`` as mono float32 at 48 kHz."""
    res = subprocess.run([ffmpeg_exe(), "-nostdin", "-hide_banner", "-loglevel", "error", "-i",
                          str(path), "-map", "0:a:0", "-f", "f32le", "-ac", "1", "-ar", "48000",
                          "-"],
                         capture_output=True, check=True)  # fmt: skip
    return np.frombuffer(res.stdout, np.float32)


def _assert_tone(path: Path, frames: int) -> None:
    """``path`` holds the sine tone, as long as its ``frames`` video frames (within one frame)."""
    sound = _sound(path)
    assert abs(len(sound) / 48000 - frames / FPS) <= 1 / FPS, (path.name, len(sound) / 48000, frames / FPS)
    peak = np.fft.rfftfreq(len(sound), 1 / 48000)[np.argmax(np.abs(np.fft.rfft(sound)))]
    assert peak == pytest.approx(TONE, abs=3), path.name


@pytest.fixture(scope="module")
def tone_clip(tmp_path_factory) -> Path:
    """An alternating-exposure clip (8 frames 160x96 at 8 fps, 3 EV) with a 440 Hz tone as its sound:
    ``synth.pan_hdr`` at 80x48 shown twice as large, so that its detail spans a few pixels as a real
    capture's does (neighbouring pixels differ by 3.8% in luminance (median), the Basler clip's by
    2.9%; rendered at full size the canvas's texture is pixel noise, 7.7%)."""
    import cv2

    from layercam import synth

    d = tmp_path_factory.mktemp("tone")
    frames = synth.pan_hdr(frames=8, size=(48, 80), ev_step=3.0, seed=1).clip.frames
    write_video(d / "silent.mp4",
                [cv2.resize(f, (160, 96), interpolation=cv2.INTER_CUBIC).clip(0, 1)
                 for f in frames], fps=FPS)
    subprocess.run([ffmpeg_exe(), "-nostdin", "-hide_banner", "-loglevel", "error", "-y", "-i",
                    str(d / "silent.mp4"), "-f", "lavfi", "-i",
                    f"sine=frequency={TONE:g}:sample_rate=48000:duration=1",
                    "-map", "0:v", "-map", "1:a", "-c:v", "copy", "-c:a", "aac",
                    str(d / "tone.mp4")], check=True)  # fmt: skip
    return d / "tone.mp4"


@pytest.fixture(scope="module")
def hdr_run(tone_clip, tmp_path_factory) -> Path:
    run = tmp_path_factory.mktemp("hdr") / "run"
    assert main(_argv("hdr-video", tone_clip, run, "--ev-step", "3")) == 0
    return run


def test_hdr_mp4_is_hevc_main10_bt2020_pq_with_hdr10_metadata(hdr_run):
    p = probe_video(hdr_run / "hdr.mp4")
    assert (p["codec"], p["profile"], p["pix_fmt"]) == ("hevc", "Main 10",
            "yuv420p10le") and "hvc1" in p["video"]  # the tag Apple's players want
    assert (p["color_range"], p["color_space"], p["color_primaries"], p["transfer"]) == ("tv",
            "bt2020nc", "bt2020", "smpte2084")
    rep = json.loads((hdr_run / "report.json").read_text())["export"]["hdr_video"]
    md, cl = p["mastering_display"], p["content_light"]
    assert md is not None and cl is not None, p["stream_side_data"] + p["frame_side_data"]
    # the stream (mp4 boxes) and the HEVC SEI both carry them: what players and ffprobe -show_streams read
    assert any("Mastering display" in s
               for s in p["stream_side_data"]) and any("Content light level" in s
               for s in p["stream_side_data"])
    assert any("Mastering display" in s
               for s in p["frame_side_data"]) and any("Content light level" in s
               for s in p["frame_side_data"])
    assert md["r"] == (0.64, 0.33) and md["g"] == (0.3, 0.6) and md["b"] == (0.15,
                       0.06) and md["wp"] == (0.3127, 0.329)  # BT.709 content
    assert (cl["max_cll"], cl["max_fall"]) == (rep["max_cll"],
            rep["max_fall"]) and 0 < cl["max_fall"] <= cl["max_cll"] <= 1000
    assert md["max"] == pytest.approx(max(rep["max_cll"], 5))
    assert p["fps"] == FPS and p["audio"] == "aac"
    assert (rep["input_primaries"]["name"] == "bt709" and "assumed" in rep["input_primaries"]["how"]
            and "reference exposure" in rep["anchor"])


def test_hdr_mp4_decodes_back_to_the_exrs_radiance(hdr_run):
    """Decoded (10-bit) and through the inverse PQ, hdr.mp4 is the EXRs' radiance times the one
    scale of the anchoring, in BT.2020: within 2% median error of the luminance on the well-exposed
    pixels (from 4 stops under diffuse white up to where the highlights' roll-off starts)."""
    from layercam.core.bt2100 import eetf, primaries_matrix

    rep = json.loads((hdr_run / "report.json").read_text())["export"]["hdr_video"]
    light, _ = read_hdr_video(hdr_run / "hdr.mp4")
    exr = np.stack([read_exr(p) for p in sorted((hdr_run / "hdr").glob("frame_*.exr"))])
    assert light.shape == exr.shape
    back = light @ np.linalg.inv(primaries_matrix("bt709", "bt2020")).T.astype(np.float32) / rep["scale"]
    lin = (exr @ primaries_matrix("bt709", "bt2020").T * rep["scale"]).max(-1)
    y = np.array([0.2126, 0.7152, 0.0722], np.float32)
    ok = (exr @ y > rep["white_radiance"] / 16) & np.isclose(eetf(lin, rep["source_peak"]), lin, rtol=1e-6)
    assert ok.mean() > 0.3
    err = np.abs(back @ y - exr @ y)[ok] / (exr @ y)[ok]
    assert np.median(err) < 0.02, np.median(err)
    assert np.all(light <= 1000 * 1.3)  # rolled off to the display's peak (codec ringing aside), never wrapped


def test_hdr_video_and_deblur_video_keep_the_sound(tone_clip, hdr_run, tmp_path):
    for name in ("hdr.mp4", "preview.mp4"):
        _assert_tone(hdr_run / name, 8)
    rep = json.loads((hdr_run / "report.json").read_text())
    assert (rep["input"]["audio"]["codec"] == "aac"
            and rep["export"]["sound"]["preview.mp4"]["copied"]
            and rep["export"]["hdr_video"]["audio"]["copied"])
    assert main(_argv("deblur-video", tone_clip, tmp_path / "deblur", "--max-frames", "6")) == 0
    _assert_tone(tmp_path / "deblur" / "deblurred.mp4", 6)  # cut with the clip
    assert probe_video(tmp_path / "deblur" / "deblurred.mp4")["fps"] == FPS


def test_a_stride_drops_the_sound_and_says_so(tone_clip, tmp_path, capsys):
    assert main(_argv("hdr-video", tone_clip, tmp_path / "run", "--ev-step", "3", "--stride", "3",
                      "--hdr-format", "none")) == 0
    err = capsys.readouterr().err
    said = [ln for ln in err.splitlines() if "sound" in ln]
    assert len(said) == 1 and said[0].startswith("warning: --stride 3"), err
    assert probe_video(tmp_path / "run" / "preview.mp4")["audio"] is None and not (tmp_path / "run"
                       / "hdr.mp4").exists()


def test_render_writes_the_runs_hlg_video_with_its_sound(hdr_run):
    assert main(["render", str(hdr_run), "--hdr-format", "hlg", "--quiet"]) == 0
    p = probe_video(hdr_run / "render" / "hdr_hlg.mp4")
    assert (p["codec"], p["profile"], p["pix_fmt"], p["color_space"], p["color_primaries"],
            p["transfer"]) == ("hevc", "Main 10", "yuv420p10le", "bt2020nc", "bt2020",
            "arib-std-b67")
    assert p["content_light"] is not None and p["mastering_display"] is not None
    _assert_tone(hdr_run / "render" / "hdr_hlg.mp4", 8)
    light, info = read_hdr_video(hdr_run / "render" / "hdr_hlg.mp4")
    side = json.loads((hdr_run / "render" / "hdr_hlg.json").read_text())
    assert info["signal"].max() <= 1.0 and light.max() <= 1000 * 1.3
    assert side["format"] == "hlg" and side["nits_white"] == 203


def test_an_ffmpeg_without_libx265_falls_back_to_none_with_one_warning(tone_clip, tmp_path, monkeypatch, capsys):
    """An ffmpeg that lacks libx265 (here: the bundled one behind a script that hides it, as a
    build without it answers) still gives every other output, hdr.mp4 left out with one line."""
    real = ffmpeg_exe()
    fake = tmp_path / "ffmpeg-without-x265"
    fake.write_text(f"""#!/bin/sh
for a in "$@"; do
  [ "$a" = -encoders ] && {{ "{real}" "$@" | grep -v libx265; exit 0; }}
  [ "$a" = libx265 ] && {{ echo "Unknown encoder 'libx265'" >&2; exit 8; }}
done
exec "{real}" "$@"
""")
    fake.chmod(0o755)
    monkeypatch.setenv("IMAGEIO_FFMPEG_EXE", str(fake))
    assert main(_argv("hdr-video", tone_clip, tmp_path / "run", "--ev-step", "3")) == 0
    warned = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("warning:")]
    assert len(warned) == 1 and "libx265" in warned[0] and "hdr.mp4 is not written" in warned[0], warned
    run = tmp_path / "run"
    assert not (run / "hdr.mp4").exists() and (run
                / "preview.mp4").exists() and len(list((run / "hdr").glob("*.exr"))) == 8
    assert json.loads((run / "report.json").read_text())["export"]["hdr_video"]["format"] == "none"
    assert main(["render", str(run), "--hdr-format", "pq", "--quiet"]) == 2  # asked for by name: one error line
    assert capsys.readouterr().err.strip().count("\n") == 0


def test_the_mapping_puts_diffuse_white_at_203_nits_and_rolls_highlights_off():
    from layercam.core import bt2100
    from layercam.io.hdr_video import HdrMapping

    white = np.full((1, 1, 3), 2.5, np.float32)  # the radiance named diffuse white
    pq = HdrMapping.anchored("pq", 2.5)
    np.testing.assert_allclose(pq.display(white), 203.0, rtol=1e-5)  # neutral: the same in BT.709 and BT.2020
    assert pq.signal(white)[0, 0, 0] == pytest.approx(0.5807, abs=1e-4)  # BT.2408: 58% PQ
    hlg = HdrMapping.anchored("hlg", 2.5)
    assert hlg.signal(white)[0, 0, 0] == pytest.approx(0.75, abs=2e-3)  # BT.2408: 75% HLG
    np.testing.assert_allclose(hlg.display(white), 203.0, rtol=1e-4)
    assert HdrMapping.anchored("pq", 2.5, nits_white=100).display(white)[0, 0, 0] == pytest.approx(100.0, rel=1e-5)
    # a ramp up to 64 x white, pure red included: rolled off below 1000 cd/m2, monotone, hue kept
    ramp = np.geomspace(0.01, 64 * 2.5, 512, dtype=np.float32)
    img = np.stack([np.stack([ramp, ramp, ramp], -1), np.stack([ramp, 0 * ramp, 0 * ramp], -1)])
    for mp in (pq, hlg):
        mp.source_peak = max(mp.peak_of(f) for f in img)
        d = mp.display(img)
        # float32 rounding at the peak
        assert d.max() <= 1000.0 * (1
                                    + 1e-6) and np.all(np.diff(d[..., 0], axis=1) >= -1e-3), mp.fmt
        red = d[1] @ np.linalg.inv(bt2100.primaries_matrix("bt709", "bt2020")).T
        assert np.abs(red[:, 1:]).max() < 1e-3 * red[:, 0].max()  # still pure red, not pushed towards white
    assert np.all(pq.signal(img) <= 1.0) and np.all(hlg.signal(img) <= 1.0)
    with pytest.raises(Exception, match="nits_white"):
        HdrMapping.anchored("pq", 1.0, nits_white=float("nan"))
