"""Video files: mp4 written and read back, errors, a truncated file, exact frame rates, variable
rates, and the input's sound carried over."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from layercam.core.errors import LayercamError
from layercam.io import load_clip, read_video, write_video

from test_io import smooth


def test_video_roundtrip_odd_size(tmp_path):
    frames = np.stack([smooth(33, 47, phase=0.2 * t) for t in range(6)])
    p = tmp_path / "v.mp4"
    write_video(p, frames, fps=12)
    assert [q.name for q in tmp_path.iterdir()] == ["v.mp4"]
    back, fps = read_video(p)
    assert back.dtype == np.uint8 and back.shape == (6, 34, 48, 3)  # padded to even
    assert fps == pytest.approx(12.0)
    err = np.abs(back[:, :33, :47].astype(np.float32) / 255.0 - frames).mean()
    assert err < 0.03

    sub, _ = read_video(p, max_frames=2, stride=2)
    np.testing.assert_array_equal(sub, back[[0, 2]])


def test_video_errors(tmp_path):
    with pytest.raises(LayercamError, match="not found"):
        read_video(tmp_path / "missing.mp4")
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(np.random.default_rng(0).bytes(4096))
    with pytest.raises(LayercamError):
        read_video(bad)
    with pytest.raises(LayercamError):
        load_clip(bad)
    with pytest.raises(ValueError):
        write_video(tmp_path / "x.mp4", np.zeros((4, 4)))
    with pytest.raises(ValueError):
        write_video(tmp_path / "x.mp4", np.zeros((2, 4, 4, 2)))
    write_video(tmp_path / "grey.mp4", np.zeros((2, 4, 4)))  # (T,H,W) grey is replicated
    assert read_video(tmp_path / "grey.mp4")[0].shape == (2, 4, 4, 3)
    assert not (tmp_path / "x.mp4").exists()


def test_video_writer_streams_frames_and_leaves_nothing_on_error(tmp_path):
    from layercam.io import VideoWriter

    with VideoWriter(tmp_path / "s.mp4", fps=10) as vw:
        for i in range(3):
            vw.add(np.full((6, 8, 3), i / 3, np.float32))  # one frame at a time
    frames, fps = read_video(tmp_path / "s.mp4")
    assert frames.shape == (3, 6, 8, 3) and fps == 10
    with pytest.raises(RuntimeError, match="stop"):
        with VideoWriter(tmp_path / "t.mp4") as vw:
            vw.add(np.zeros((6, 8, 3), np.uint8))
            raise RuntimeError("stop")
    assert not list(tmp_path.glob("*t.*mp4")), "an interrupted video leaves no file, not even a temporary one"
    with pytest.raises(ValueError, match="must all be"):
        with VideoWriter(tmp_path / "u.mp4") as vw:
            vw.add(np.zeros((6, 8, 3), np.uint8))
            vw.add(np.zeros((4, 8, 3), np.uint8))
    write_video(tmp_path / "g.mp4", (np.zeros((5, 7)) for _ in range(2)))  # any iterable, odd sizes padded
    assert read_video(tmp_path / "g.mp4")[0].shape == (2, 6, 8, 3)


def test_mp4_complete_tells_a_whole_video_from_a_truncated_one(tmp_path):
    """imageio-ffmpeg does not raise when ffmpeg fails at the end (a full disk: "Error writing
    trailer") and leaves a truncated file; the writer checks the container's top-level boxes before
    the file takes its name. A whole video passes; the same cut short anywhere, or without its
    index, does not."""
    from layercam.io.video import mp4_complete

    write_video(tmp_path / "v.mp4", np.random.default_rng(0).uniform(0, 1, (6, 16, 24, 3)))
    data = (tmp_path / "v.mp4").read_bytes()
    assert mp4_complete(tmp_path / "v.mp4")
    for cut in (len(data) - 1, len(data) // 2, 40, 7):
        (tmp_path / "cut.mp4").write_bytes(data[:cut])
        assert not mp4_complete(tmp_path / "cut.mp4"), cut
    (tmp_path / "ftyp.mp4").write_bytes(data[: int.from_bytes(data[:4], "big")])  # the first box alone
    assert not mp4_complete(tmp_path / "ftyp.mp4")


# -- timing and sound (issue 41) -----------------------------------------------------------------
def _ffmpeg(*args: str) -> None:
    import subprocess

    from layercam.io.ffmpeg import ffmpeg_exe

    subprocess.run([ffmpeg_exe(), "-nostdin", "-hide_banner", "-loglevel", "error", "-y", *args], check=True)


def _tone(path: Path) -> tuple[np.ndarray, int]:
    """The first audio stream of ``path`` decoded to mono float32 at 48 kHz."""
    import subprocess

    from layercam.io.ffmpeg import ffmpeg_exe

    pcm = subprocess.run([ffmpeg_exe(), "-nostdin", "-hide_banner", "-loglevel", "error", "-i",
                          str(path), "-map", "0:a:0", "-f", "f32le", "-ac", "1", "-ar", "48000",
                          "-"],
                         capture_output=True, check=True).stdout
    return np.frombuffer(pcm, np.float32), 48000


def test_rate_text_is_exact_for_ntsc_rates_and_read_video_keeps_them(tmp_path):
    from layercam.io.ffmpeg import rate_text

    assert rate_text(24.0) == "24" and rate_text(12.5) == "25/2" and rate_text(30000
        / 1001) == "30000/1001" and rate_text(24000 / 1001) == "24000/1001"
    _ffmpeg("-f", "lavfi", "-i", "testsrc2=size=32x32:rate=30000/1001", "-frames:v", "5",
            "-pix_fmt", "yuv420p", str(tmp_path / "ntsc.mp4"))
    frames, fps = read_video(tmp_path / "ntsc.mp4")
    assert fps == pytest.approx(30000 / 1001, abs=1e-9)  # not ffmpeg's printed 29.97
    write_video(tmp_path / "back.mp4", frames, fps=fps)
    from layercam.io.hdr_video_read import probe_video

    assert "30000/1001" == rate_text(read_video(tmp_path / "back.mp4")[1]) and probe_video(tmp_path
        / "back.mp4")["tbr"] == pytest.approx(29.97)


def test_a_variable_rate_video_is_said_and_decoded_at_a_constant_rate(tmp_path):
    # a phone's 30 fps that slows to 15 after a second (every other frame left out): 45 frames in 1.9 s
    _ffmpeg("-f", "lavfi", "-i", "testsrc2=size=32x32:rate=30", "-t", "2", "-vf",
            "select='lt(t\\,1)+not(mod(n\\,2))'", "-fps_mode", "vfr", "-pix_fmt", "yuv420p",
            str(tmp_path / "vfr.mp4"))
    clip = load_clip(tmp_path / "vfr.mp4")
    info = clip.meta["video"]
    assert info["variable"] and info["tbr"] == 30 and info["fps"] < 25
    assert clip.fps == 30 and clip.T == pytest.approx(58, abs=2)  # frames at a constant 30 fps: the clip keeps its time
    assert any("variable frame rate" in n and "30 fps" in n for n in clip.meta["notes"])
    steady = tmp_path / "cfr.mp4"
    write_video(steady, clip.frames[:4], fps=30)
    assert not load_clip(steady).meta["video"]["variable"] and not load_clip(steady).meta["notes"]


def test_the_clips_sound_is_planned_cut_with_max_frames_and_dropped_with_a_stride(tmp_path):
    _ffmpeg("-f", "lavfi", "-i", "testsrc2=size=32x32:rate=8", "-f", "lavfi", "-i",
            "sine=frequency=440:sample_rate=48000", "-t", "2", "-pix_fmt", "yuv420p", "-c:a", "aac",
            "-shortest", str(tmp_path / "a.mp4"))
    whole = load_clip(tmp_path / "a.mp4")
    assert whole.meta["audio"] == {"path": str((tmp_path / "a.mp4").resolve()), "codec": "aac",
                                   "duration": None} and not whole.meta["notes"]
    assert load_clip(tmp_path / "a.mp4", max_frames=16).meta["audio"]["duration"] is None  # all 16 frames: nothing cut
    assert load_clip(tmp_path / "a.mp4", max_frames=6).meta["audio"]["duration"] == pytest.approx(6 / 8)
    strided = load_clip(tmp_path / "a.mp4", stride=2)
    assert strided.meta["audio"] is None and any("--stride 2" in n and "sound" in n for n in strided.meta["notes"])
    assert (load_clip(tmp_path / "a.mp4").meta["primaries"]["name"] == "bt709"
            and "assumed" in whole.meta["primaries"]["how"])
    silent = tmp_path / "s.mp4"
    write_video(silent, whole.frames[:3], fps=8)
    assert load_clip(silent).meta["audio"] is None


@pytest.mark.parametrize("codec", ["aac", "pcm_s16le"])
def test_video_writer_carries_the_sound_over_unchanged_and_cut(tmp_path, codec):
    from layercam.io import VideoWriter

    src = tmp_path / ("in.mov" if codec.startswith("pcm") else "in.mp4")
    _ffmpeg("-f", "lavfi", "-i", "testsrc2=size=32x32:rate=8", "-f", "lavfi", "-i",
            "sine=frequency=440:sample_rate=48000", "-t", "2", "-pix_fmt", "yuv420p", "-c:a", codec,
            "-shortest", str(src))
    frames, fps = read_video(src)
    for cut in (None, 0.75):
        out = tmp_path / f"out_{cut}.mp4"
        n = len(frames) if cut is None else 6
        with VideoWriter(out, fps=fps, audio={"path": str(src), "codec": codec, "duration": cut}) as vw:
            for f in frames[:n]:
                vw.add(f)
        assert vw.audio_info["kept"]
        sound, rate = _tone(out)
        assert abs(len(sound) / rate - n / fps) <= 1 / fps  # the same duration as the video, within one frame
        spectrum = np.abs(np.fft.rfft(sound))
        assert np.fft.rfftfreq(len(sound), 1 / rate)[np.argmax(spectrum)] == pytest.approx(440, abs=3)
    assert not [p for p in tmp_path.iterdir() if ".tmp" in p.name]
    gone = tmp_path / "gone.mp4"
    with VideoWriter(gone, fps=fps,
                     audio={"path": str(tmp_path / "moved.mp4"), "codec": "aac",
                            "duration": None}) as vw:
        vw.add(frames[0])
    assert not vw.audio_info["kept"] and "no longer there" in vw.audio_info["why"] and read_video(gone)[0].shape[0] == 1


def test_the_output_stream_line_is_read_whole():
    """The decoder's log is polled while ffmpeg writes it: a line read before its rate is written
    must not be taken (the clip's frame rate then fell back to 24 fps on a loaded machine)."""
    from layercam.io.video import _OUT_STREAM

    head = ("Input #0, mov,mp4\n  Duration: 00:00:01.00\nOutput #0, rawvideo, to 'pipe:':\n  "
            "Stream #0:0: Video: rawvideo (RGB[24] / 0x18424752), rgb24(pc), 160x96")
    assert _OUT_STREAM.search(head) is None
    assert _OUT_STREAM.search(head + ", q=2-31") is None
    m = _OUT_STREAM.search(head + ", q=2-31, 368 kb/s, 8 fps, 8 tbn\n")
    assert m and (m.group(1), m.group(2)) == ("160", "96") and "8 fps" in m.group(3)
