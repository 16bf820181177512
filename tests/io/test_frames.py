"""Clips kept on disk (issue 42): frames decoded once, a frame at a time, into the run's cache as
uint8 (uint16 for 16-bit input), read back as the float32 values the loader gave before; flows and
masks on disk; the analysis, the bootstrap and the alpha grid bounded whatever the clip's length."""

from __future__ import annotations

import numpy as np
import pytest

from layercam.io.frames import DiskArray, Frames, TempArray


def test_disk_array_reads_rows_and_gathers_without_keeping_pages(tmp_path):
    a = np.arange(5 * 4 * 3 * 2, dtype=np.float16).reshape(5, 4, 3, 2)
    d = DiskArray.create(tmp_path / "a.raw", np.float16, a.shape)
    d[0:3] = a[:3]
    d[3] = a[3]
    d[4:5] = a[4:]
    d.close()
    r = DiskArray(tmp_path / "a.raw", np.float16, a.shape)
    assert np.array_equal(r[2], a[2]) and np.array_equal(r[1:4], a[1:4]) and np.array_equal(r[::2], a[::2])
    assert np.array_equal(r[-1, 1:3], a[-1, 1:3]) and np.array_equal(np.asarray(r), a) and len(r) == 5
    t, y, x = np.array([0, 4, 2]), np.array([3, 0, 1]), np.array([2, 1, 0])
    assert np.array_equal(r.gather(t, y, x), a[t, y, x])
    assert np.array_equal(r[[1, 3]], a[[1, 3]])
    with pytest.raises(ValueError, match="holds"):
        DiskArray(tmp_path / "a.raw", np.float16, (6, 4, 3, 2))  # a file shorter than the array


def test_rows_of_a_disk_array_are_a_view_that_reads_and_travels(tmp_path):
    """``rows(t0, t1)`` (a window of a long clip): the same values as a slice, gathered and
    written through the same file, sent to another process by path; closing it leaves its owner
    open. ``Frames.rows`` likewise, in memory or on disk."""
    import pickle

    a = np.arange(6 * 4 * 3, dtype=np.uint8).reshape(6, 4, 3)
    d = DiskArray.create(tmp_path / "a.raw", np.uint8, a.shape)
    d[0:6] = a
    v = d.rows(2, 5)
    assert v.shape == (3, 4, 3) and np.array_equal(np.asarray(v), a[2:5]) and np.array_equal(v[-1],
                       a[4]) and np.array_equal(v[1:], a[3:5])
    t, y = np.array([0, 2, 1]), np.array([3, 0, 2])
    assert np.array_equal(v.gather(t, y), a[2:5][t, y]) and np.array_equal(v.rows(1, 2)[0], a[3])
    v[0] = 7
    assert np.all(d[2] == 7)
    back = pickle.loads(pickle.dumps(v))
    assert np.array_equal(np.asarray(back), np.asarray(v))
    v.close()
    assert np.array_equal(d[5], a[5])  # the owner's file is still open
    with pytest.raises(TypeError, match="unlinked"):
        pickle.dumps(TempArray(np.uint8, (3, 2), tmp_path).rows(0, 2))
    f = Frames(DiskArray(tmp_path / "a.raw", np.uint8, (2, 4, 1, 3)))
    assert f.rows(1, 2).on_disk and np.array_equal(f.rows(1, 2)[0], f[1])
    m = Frames(np.ones((3, 2, 2, 3), np.float32))
    assert np.shares_memory(m.rows(1, 3).raw, m.raw)


def test_a_window_of_a_clip_on_disk_reads_nothing(tmp_path):
    """A long clip's window (layercam.pipelines.windows) holds its frames, masks and flow as views of the
    whole clip's files."""
    from layercam.io import load_clip
    from layercam.pipelines.windows.plan import rows
    from layercam.pipelines.windows.plan import sub_clip, sub_flow
    from layercam.vision.flow_store import FlowArrays

    v = _video(tmp_path / "v.mp4", n=5)
    clip = load_clip(v, cache=tmp_path / "cache")
    w = sub_clip(clip, 1, 4)
    assert w.T == 3 and w.frames.on_disk and np.array_equal(w.frames[0], clip.frames[1]) and w.meta["window"] == [1, 4]
    flow = FlowArrays(fw=DiskArray(clip.frames.raw.path, np.uint8, (4, 2, 2, 2)), homs=np.repeat(np.eye(3)[None], 4, 0))
    sub = sub_flow(flow, 1, 4)
    assert isinstance(sub.fw, DiskArray) and len(sub.fw) == 2 and sub.homs.shape == (2, 3, 3) and sub.pairs == 2
    assert list(sub) == ["fw", "homs"] and sub.bw is None and sub.grid == (2, 2)
    assert np.array_equal(rows(np.arange(5), 1, 3), [1, 2])


def test_temp_array_leaves_no_file(tmp_path):
    t = TempArray(np.bool_, (3, 2, 2), tmp_path)
    t[1] = True
    assert list(tmp_path.iterdir()) == [] and np.asarray(t).sum() == 4


def test_frames_read_as_the_float32_the_loader_gave(tmp_path):
    rng = np.random.default_rng(0)
    u8 = rng.integers(0, 256, (3, 4, 5, 3), dtype=np.uint8)
    f = Frames(u8)
    want = u8.astype(np.float32) / 255.0
    assert f.shape == (3, 4, 5, 3) and f.dtype == np.float32 and len(f) == 3
    assert np.array_equal(f[1], want[1]) and np.array_equal(f[0:2], want[0:2]) and np.array_equal(np.asarray(f), want)
    assert np.array_equal(np.stack(list(f)), want) and np.isclose(f.mean(), want.mean())
    u16 = rng.integers(0, 65536, (2, 3, 3, 3), dtype=np.uint16)
    assert np.array_equal(Frames(u16)[1], u16[1].astype(np.float32) / 65535.0)


def _video(path, n=6, hw=(24, 32)):
    from layercam.io import write_video

    rng = np.random.default_rng(1)
    base = rng.random((hw[0] * 2, hw[1] * 2, 3)).astype(np.float32)
    write_video(path, [base[t : t + hw[0], t : t + hw[1]] for t in range(n)], fps=10)
    return path


def test_a_video_is_decoded_once_into_the_cache_and_read_as_before(tmp_path):
    from layercam.io import load_clip, probe_clip, read_video

    v = _video(tmp_path / "v.mp4")
    u8, _ = read_video(v)
    cache = tmp_path / "run" / "cache"
    clip = load_clip(v, cache=cache)
    assert clip.frames.on_disk and clip.frames.raw.dtype == np.uint8 and (clip.T, clip.H, clip.W) == (6, 24, 32)
    assert np.array_equal(np.asarray(clip.frames), u8.astype(np.float32) / 255.0)  # what load_clip gave in float32
    folder = next(cache.glob("frames-*"))
    stamp = (folder / "frames.raw").stat().st_mtime_ns
    again = load_clip(v, cache=cache)  # mapped, not decoded again
    assert (folder / "frames.raw").stat().st_mtime_ns == stamp and again.fingerprint() == clip.fingerprint()
    assert load_clip(v).fingerprint() == clip.fingerprint()  # no cache: an unlinked temporary file
    assert probe_clip(v)["frames"] == 6 and probe_clip(v, stride=2, resize=0.5) == {"kind": "video",
                                                       "frames": 3, "width": 16, "height": 12,
                                                       "source_size": (32, 24), "bit_depth": 8}
    small = load_clip(v, cache=cache, resize="16x12", max_frames=4)
    assert small.frames.raw.dtype == np.uint8 and (small.T, small.H, small.W) == (4, 12,
                                                   16) and len(list(cache.glob("frames-*"))) == 2


def test_16bit_images_are_kept_in_16_bits(tmp_path):
    from layercam.io import load_clip, write_png

    rng = np.random.default_rng(2)
    imgs = [rng.random((8, 10, 3)).astype(np.float32) for _ in range(3)]
    for i, im in enumerate(imgs):
        write_png(tmp_path / f"f{i}.png", im, bit_depth=16)
    clip = load_clip(tmp_path, cache=tmp_path / "cache")
    assert clip.bit_depth == 16 and clip.frames.raw.dtype == np.uint16
    assert np.abs(clip.frames[2] - imgs[2]).max() <= 0.5 / 65535 + 1e-7


def test_the_flow_store_holds_what_the_whole_clip_functions_give(tmp_path):
    from layercam.vision import flow, flow_store
    from layercam.core.config import FlowConfig
    from layercam.synth import moving_object

    fr = np.asarray(moving_object(frames=5, size=(40, 48), seed=0).clip.frames)
    fw, bw = flow.compute_flow(fr, method="dis_fast", progress=False)
    want = flow.pair_arrays(fr, fw, bw)
    summary = flow_store.compute(Frames(fr), tmp_path, FlowConfig(method="dis_fast"))
    got = flow_store.load(tmp_path)
    assert summary["pairs"] == 4 and isinstance(got.fw, DiskArray) and got.grid == (40, 48) and got.pairs == 4
    assert np.array_equal(np.asarray(got["fw"]),
                          fw.astype(np.float16)) and np.array_equal(np.asarray(got["bw"]),
                          bw.astype(np.float16))
    for k in ("fw_ok", "bw_ok", "vis", "homs"):
        assert np.array_equal(np.asarray(got[k]), want[k]), k


def test_initial_log2_is_the_median_of_every_pixel():
    import math

    from layercam.camera.tone import initial_log2

    rng = np.random.default_rng(3)
    for q in (True, False):
        f = rng.random((5, 7, 9, 3)).astype(np.float32)
        if q:
            f = np.round(f * 255).astype(np.float32) / np.float32(255)
        dt = rng.normal(size=5).astype(np.float32)
        c = np.clip(f.mean(-1), 0.02, 0.98)
        z = np.log(c / (1 - c)) / math.log(2) - dt[:, None, None]
        assert initial_log2(f, dt, "learned", 1.0) == float(np.median(z.astype(np.float32)))


def test_the_alpha_grid_of_a_long_clip_stops_growing_and_old_grids_load():
    from layercam.scene.encodings import DenseGrid3D

    short = DenseGrid3D(3, 64, 40, max_cells=64 * 64 * 50)
    long = DenseGrid3D(3, 64, 400, max_cells=64 * 64 * 50)
    assert short.shapes == DenseGrid3D(3, 64, 40).shapes  # below the cap: one slice per frame, as before
    assert long.shapes[-1] == (50, 64) and long.shapes[0][0] == 12
    old = DenseGrid3D(3, 64, 400)  # saved before the cap
    long.load_state_dict(old.state_dict())
    assert long.shapes == old.shapes and all(a.shape == b.shape for a, b in zip(long.grids, old.grids))


def test_a_long_two_layer_clip_is_segmented_in_windows_and_resumes(tmp_path, monkeypatch):
    """More frames than ``segment.long.SEG_FRAMES``: masks on disk, per window; the run finishes, and
    again (cached) gives the same outputs."""
    from layercam.vision.segment import long as seg_long
    from layercam import synth
    from layercam.core.presets import load_config
    from layercam.io import Exposures
    from layercam.pipelines.tasks import run_task

    from conftest import TINY

    monkeypatch.setattr(seg_long, "SEG_FRAMES", 6)
    monkeypatch.setattr(seg_long, "SEG_MARGIN", 1)
    scene = synth.moving_object(frames=10, size=(40, 40), seed=0)
    ex = Exposures(np.zeros(10), "none", None, "none", "test")
    cfg = load_config("fast", TINY + ["model.layers=2", "train.steps=20"])
    ctx = run_task("hdr-video", scene.clip, ex, cfg, tmp_path / "run", progress=False)
    boot = ctx.results["bootstrap"]
    assert boot.foreground["windows"] == 3 and isinstance(boot.masks, DiskArray) and boot.masks.shape == (10, 40, 40)
    assert np.asarray(boot.masks).any()
    import json

    mem = json.loads((tmp_path / "run" / "report.json").read_text())["memory"]
    assert (set(mem["estimate"]) == {"before", "after_analysis"}
            and mem["estimate"]["before"]["memory"] > 0 and mem["peak_rss_bytes"] > 0)
    first = (tmp_path / "run" / "hdr" / "frame_00009.exr").read_bytes()
    again = run_task("hdr-video", scene.clip, ex, cfg, tmp_path / "run", progress=False)
    assert all(t["cached"]
               for t in again.times.values()) and (tmp_path / "run" / "hdr"
                                                   / "frame_00009.exr").read_bytes() == first


def test_the_analysis_of_a_long_clip_reads_windows():
    from layercam.vision.analyse import MOTION_PAIRS, motion_windows

    assert motion_windows(MOTION_PAIRS) == [(0, MOTION_PAIRS)]
    w = motion_windows(1000)
    assert sum(b - a for a, b in w) <= MOTION_PAIRS and w[0][0] == 0 and w[-1][1] == 1000


def test_masks_of_a_clip_on_disk_are_on_disk_too(tmp_path):
    from layercam.io import load_clip, write_png
    from layercam.io.masks import load_masks

    v = _video(tmp_path / "v.mp4", n=3)
    (tmp_path / "m").mkdir()
    for t in range(3):
        m = np.zeros((24, 32), np.float32)
        m[t : t + 5, 4:9] = 1.0
        write_png(tmp_path / "m" / f"{t:03d}.png", m)
    on_disk = load_masks(tmp_path / "m", load_clip(v, cache=tmp_path / "cache"))
    in_memory = load_masks(tmp_path / "m", load_clip(v))
    assert isinstance(on_disk, DiskArray) and on_disk.dtype == np.uint8 and in_memory.dtype == np.float32
    assert np.array_equal(np.asarray(on_disk), in_memory) and in_memory.sum() == 75


def test_the_estimate_grows_with_the_clip_on_disk_not_in_memory(tmp_path):
    from layercam.core.presets import load_config
    from layercam.core.errors import LayercamError
    from layercam.engine.estimate import check, estimate

    cfg = load_config("fast")
    short, long = (estimate({"frames": n, "width": 854, "height": 480, "bit_depth": 8}, cfg) for n in (48, 768))
    assert long["memory"] < 1.3 * short["memory"] and long["disk"] > 4 * short["disk"]
    assert (long["disk_parts"]["frames"] == 16 * short["disk_parts"]["frames"]
            and long["disk_parts"]["flow"] > 16 * short["disk_parts"]["flow"])  # 767 pairs, 47
    assert short["assumed"] == {"layers": 2, "blur": "off"}  # the analysis's costliest plausible choice
    win = estimate({"frames": 768, "width": 854, "height": 480, "bit_depth": 8}, cfg, windows=[(0, 400), (368, 768)])
    # one window's model at a time, each window's files
    assert win["windows"] == 2 and win["memory"] <= long["memory"] and win["disk"] > long["disk"]
    assert (win["disk_parts"]["checkpoints"] > long["disk_parts"]["checkpoints"]
            and win["disk_parts"]["frames"] == long["disk_parts"]["frames"])
    huge = estimate({"frames": 4, "width": 100000, "height": 100000, "bit_depth": 8}, cfg)
    with pytest.raises(LayercamError, match="--resize"):
        check(huge, tmp_path)
    check(short, tmp_path)  # fits this machine
