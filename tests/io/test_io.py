"""Tests of layercam.io: image/video/EXR round trips, clip loading, atomic writes, errors."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, strategies as st
from hypothesis.extra import numpy as hnp

from layercam.core.errors import LayercamError
from layercam.io import (Clip, atomic_write, ensure_writable_dir, load_clip, read_exr, read_image,
                         write_exr, write_png, write_video)
from layercam.io.images import read_exif_exposure

from props import props

from conftest import SHARED_DATA as DATA  # $LAYERCAM_DATA, else beside the checkout
needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"shared data folder {DATA} is absent")


def smooth(h: int = 32, w: int = 48, phase: float = 0.0) -> np.ndarray:
    """A smooth RGB test image (H,W,3) float32 in [0.1, 0.9]."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    r = 0.5 + 0.4 * np.sin(x / w * 2 * np.pi + phase)
    g = 0.5 + 0.4 * np.cos(y / h * 2 * np.pi + phase)
    b = 0.5 + 0.4 * np.sin((x + y) / (w + h) * 2 * np.pi)
    return np.stack([r, g, b], axis=-1).astype(np.float32)


def write_frames(folder: Path, n: int, h: int = 16, w: int = 24, fmt: str = "png") -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i in range(n):
        img = np.full((h, w, 3), (i + 1) / (n + 1), np.float32)
        p = folder / f"f{i}.{fmt}"  # f0..f9, f10: natural sort must order these
        write_png(p, img) if fmt == "png" else _write_cv(p, img)
        paths.append(p)
    return paths


def _write_cv(p: Path, img: np.ndarray) -> None:
    import cv2

    cv2.imwrite(str(p), np.round(img[:, :, ::-1] * 255).astype(np.uint8))


# ------------------------------------------------------------------------ atomic


def test_atomic_write_replaces_and_cleans(tmp_path):
    target = tmp_path / "out" / "a.txt"
    atomic_write(target, lambda p: p.write_text("one"))
    atomic_write(target, lambda p: p.write_text("two"))
    assert target.read_text() == "two"

    def boom(p: Path) -> None:
        assert p.suffix == ".txt" and p.parent == target.parent
        p.write_text("partial")
        raise RuntimeError("encoder failed")

    with pytest.raises(RuntimeError):
        atomic_write(target, boom)
    assert target.read_text() == "two"
    assert sorted(os.listdir(target.parent)) == ["a.txt"]


def test_ensure_writable_dir_errors(tmp_path):
    assert ensure_writable_dir(tmp_path / "x" / "y").is_dir()
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with pytest.raises(LayercamError):
        ensure_writable_dir(blocker)
    with pytest.raises(LayercamError):
        ensure_writable_dir(blocker / "sub")
    with pytest.raises(LayercamError):
        write_png(blocker / "sub" / "a.png", smooth())


# ------------------------------------------------------------------------ images


@pytest.mark.parametrize("depth,tol", [(8, 0.5 / 255 + 1e-6), (16, 0.5 / 65535 + 1e-6)])
def test_png_roundtrip(tmp_path, depth, tol):
    img = smooth()
    p = tmp_path / "a.png"
    write_png(p, img, bit_depth=depth)
    back, d = read_image(p, return_bit_depth=True)
    assert d == depth and back.shape == img.shape and back.dtype == np.float32
    assert np.abs(back - img).max() <= tol
    assert [q.name for q in tmp_path.iterdir()] == ["a.png"]


def test_grey_and_16bit_and_rgba_become_rgb(tmp_path):
    import cv2

    grey16 = (np.linspace(0, 65535, 12 * 10).reshape(12, 10)).astype(np.uint16)
    cv2.imwrite(str(tmp_path / "g.png"), grey16)
    img, d = read_image(tmp_path / "g.png", return_bit_depth=True)
    assert d == 16 and img.shape == (12, 10, 3)
    np.testing.assert_allclose(img[..., 1], grey16 / 65535.0, atol=1e-6)

    bgra = np.zeros((4, 5, 4), np.uint8)
    bgra[..., 2] = 255  # red in BGR order
    bgra[..., 3] = 7
    cv2.imwrite(str(tmp_path / "r.png"), bgra)
    img = read_image(tmp_path / "r.png")
    assert img.shape == (4, 5, 3) and np.all(img[..., 0] == 1) and np.all(img[..., 1:] == 0)

    grey_png = tmp_path / "g8.png"
    write_png(grey_png, np.full((3, 4), 0.5, np.float32))
    assert read_image(grey_png).shape == (3, 4, 3)


def test_float_tif_clipped(tmp_path):
    import cv2

    f = np.array([[[-1.0, 0.5, 2.0]]], np.float32).repeat(3, 0).repeat(3, 1)
    cv2.imwrite(str(tmp_path / "f.tif"), f)
    img, d = read_image(tmp_path / "f.tif", return_bit_depth=True)
    assert d == 32 and img.min() >= 0 and img.max() <= 1


def test_image_errors(tmp_path):
    with pytest.raises(LayercamError, match="not found"):
        read_image(tmp_path / "missing.png")
    bad = tmp_path / "bad.png"
    bad.write_bytes(os.urandom(200))
    with pytest.raises(LayercamError, match="cannot decode"):
        read_image(bad)
    with pytest.raises(ValueError):
        write_png(tmp_path / "x.png", np.zeros((2, 2, 4)))
    with pytest.raises(ValueError):
        write_png(tmp_path / "x.png", np.full((2, 2, 3), np.nan))
    assert read_exif_exposure(tmp_path / "bad.png") is None


# ------------------------------------------------------------------------ EXR


@pytest.mark.parametrize("half,rtol", [(True, 1e-3), (False, 0.0)])
def test_exr_roundtrip(tmp_path, half, rtol):
    img = smooth(8, 12) * 100.0  # HDR values above 1 survive
    p = tmp_path / "a.exr"
    write_exr(p, img, half=half)
    back = read_exr(p)
    assert back.shape == img.shape and back.dtype == np.float32
    np.testing.assert_allclose(back, img, rtol=rtol, atol=1e-6)
    assert [q.name for q in tmp_path.iterdir()] == ["a.exr"]


def test_exr_errors(tmp_path):
    img = smooth(4, 4)
    img[1, 1, 1] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        write_exr(tmp_path / "n.exr", img)
    assert not any(tmp_path.iterdir())
    with pytest.raises(ValueError):
        write_exr(tmp_path / "s.exr", np.zeros((4, 4)))
    with pytest.raises(LayercamError):
        read_exr(tmp_path / "missing.exr")
    (tmp_path / "bad.exr").write_bytes(b"garbage" * 20)
    with pytest.raises(LayercamError):
        read_exr(tmp_path / "bad.exr")


# ------------------------------------------------------------------------ video


# ------------------------------------------------------------------------ clips


def test_load_folder_natural_order_stride_max(tmp_path):
    write_frames(tmp_path / "fr", 11)
    (tmp_path / "fr" / "notes.txt").write_text("ignored")
    clip = load_clip(tmp_path / "fr")
    assert isinstance(clip, Clip) and (clip.T, clip.H, clip.W) == (11, 16, 24)
    assert clip.names[:3] == ["f0", "f1", "f2"] and clip.names[-1] == "f10"
    assert np.all(np.diff(clip.frames.mean(axis=(1, 2, 3))) > 0)
    assert clip.frames.dtype == np.float32 and clip.bit_depth == 8

    sub = load_clip(tmp_path / "fr", stride=3, max_frames=2, resize=0.5)
    assert sub.names == ["f0", "f3"] and (sub.H, sub.W) == (8, 12)
    assert sub.meta["frame_indices"] == [0, 3]
    sized = load_clip(tmp_path / "fr", max_frames=1, resize="10x6")
    assert (sized.H, sized.W) == (6, 10)


def test_load_list_glob_and_fingerprint(tmp_path):
    paths = write_frames(tmp_path, 3)
    clip = load_clip([str(p) for p in reversed(paths)])
    assert clip.names == ["f2", "f1", "f0"]
    assert clip.exif_exposures == [None, None, None]
    g = load_clip(str(tmp_path / "f*.png"))
    assert g.names == ["f0", "f1", "f2"]
    fp = g.fingerprint()
    assert fp == load_clip(tmp_path).fingerprint() and fp != clip.fingerprint()


def test_load_video_clip(tmp_path):
    frames = np.stack([smooth(16, 24, phase=0.3 * t) for t in range(7)])
    write_video(tmp_path / "v.mp4", frames, fps=30)
    clip = load_clip(tmp_path / "v.mp4", stride=2, max_frames=3, resize="12x8")
    assert (clip.T, clip.H, clip.W) == (3, 8, 12) and clip.fps == pytest.approx(30)
    assert clip.names == ["00000", "00002", "00004"]
    assert clip.exif_exposures is None and clip.frames.max() <= 1.0


def test_mixed_sizes_and_bit_depths(tmp_path):
    import cv2

    write_png(tmp_path / "a.png", smooth(8, 8))
    write_png(tmp_path / "b.png", smooth(8, 10))
    with pytest.raises(LayercamError, match="b.png"):
        load_clip(tmp_path)
    clip = load_clip(tmp_path, resize="6x4")
    assert (clip.T, clip.H, clip.W) == (2, 4, 6)
    (tmp_path / "b.png").unlink()
    cv2.imwrite(str(tmp_path / "b.png"), np.zeros((8, 8, 3), np.uint16))
    assert load_clip(tmp_path).bit_depth == 16


def test_clip_input_errors(tmp_path):
    with pytest.raises(LayercamError, match="not found"):
        load_clip(tmp_path / "nothing_here")
    (tmp_path / "empty").mkdir()
    with pytest.raises(LayercamError, match="no images"):
        load_clip(tmp_path / "empty")
    with pytest.raises(LayercamError):
        load_clip([])
    with pytest.raises(LayercamError, match="no images match"):
        load_clip(str(tmp_path / "*.jpg"))
    write_frames(tmp_path / "fr", 2)
    for bad in ("abc", "0", "-1x5", -2):
        with pytest.raises(LayercamError):
            load_clip(tmp_path / "fr", resize=bad)
    with pytest.raises(LayercamError):
        load_clip(tmp_path / "fr", stride=0)
    with pytest.raises(LayercamError):
        load_clip(tmp_path / "fr", max_frames=0)


def test_clip_validates_shapes():
    with pytest.raises(ValueError):
        Clip(frames=np.zeros((2, 4, 4)), source="x", names=["a", "b"])
    with pytest.raises(ValueError):
        Clip(frames=np.zeros((2, 4, 4, 3)), source="x", names=["a"])


# ------------------------------------------------------------------------ real data


@pytest.mark.data
@needs_data
def test_real_altexp_video_loads():
    clip = load_clip(DATA / "altexp_video_basler" / "clip_2exp_3stop.mp4")
    assert (clip.T, clip.H, clip.W) == (74, 136, 256)
    assert clip.fps == pytest.approx(24, abs=0.1)
    m = clip.frames.mean(axis=(1, 2, 3))
    assert m[1] > m[0] and m[3] > m[2]  # frame 0 is the low exposure


@pytest.mark.data
@needs_data
def test_real_exif_jpegs_and_tiffs():
    clip = load_clip(DATA / "bracket_frobisher_exif", resize=0.1)
    assert clip.names == ["IMG_2600", "IMG_2601", "IMG_2602"]
    assert clip.exif_exposures == pytest.approx([1 / 8, 1.0, 8.0])
    tifs = sorted((DATA / "focus_pairs_lytro" / "color").glob("*.tif"))[:2]
    assert load_clip(tifs).frames.shape[-1] == 3


@props(20)
@given(img=hnp.arrays(np.float32, st.tuples(st.integers(1, 5), st.integers(1, 5), st.just(3)),
                      elements=st.floats(0, 65504, width=32)), half=st.booleans())
def test_exr_roundtrip_finite_non_negative(img, half):
    from layercam.io import read_exr, write_exr

    with tempfile.TemporaryDirectory() as d:
        write_exr(Path(d) / "a.exr", img, half=half)
        back = read_exr(Path(d) / "a.exr")
    assert back.shape == img.shape and np.isfinite(back).all() and (back >= 0).all()


def test_exr_refuses_non_finite_and_half_overflow(tmp_path):
    from layercam.io import write_exr

    for bad in (np.nan, np.inf):
        with pytest.raises(ValueError, match="non-finite"):
            write_exr(tmp_path / "x.exr", np.full((2, 2, 3), bad, np.float32))
    with pytest.raises(ValueError, match="float16"):
        write_exr(tmp_path / "y.exr", np.full((2, 2, 3), 1e5, np.float32), half=True)
    assert not (tmp_path / "x.exr").exists() and not (tmp_path / "y.exr").exists()


def test_a_full_disk_is_one_clear_error_and_leaves_no_temporary_file(tmp_path):
    """``atomic_write``: a writer that runs out of disk (an ``OSError`` ENOSPC, as numpy and PNG
    writers raise it; torch's zip writer's and OpenEXR's ``RuntimeError``) ends as one
    ``LayercamError`` naming the file and the full disk, with no temporary file left; the file it
    would have replaced stays; other errors pass through unchanged."""
    import errno

    target = tmp_path / "a.exr"
    target.write_text("before")

    def fails(err):
        def writer(p: Path) -> None:
            p.write_text("partial")
            raise err
        return writer

    for err, said in [
        (OSError(errno.ENOSPC, "No space left on device"), "(the disk is full): No space left on device"),
        (RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 96640 vs 96528"),
         "(is the disk full?)"),
        (RuntimeError('Failed to write pixel data to image file "x.exr". No space left on device.'),
         "(the disk is full)"),
    ]:
        with pytest.raises(LayercamError, match="cannot write .*a.exr") as e:
            atomic_write(target, fails(err))
        assert said in str(e.value) and "\n" not in str(e.value)
        assert target.read_text() == "before" and sorted(os.listdir(tmp_path)) == ["a.exr"]
    with pytest.raises(ValueError, match="not about the disk"):
        atomic_write(target, fails(ValueError("not about the disk")))


def test_a_failed_command_gives_back_its_staging_folders(tmp_path):
    """``partials_removed_on_error`` (around ``render`` and ``edit``): a command that fails midway
    (a full disk) removes the ``.partial-*`` folders it wrote into, and what it finished stays; one
    that succeeds is left as it is."""
    from layercam.io.atomic import commit_staged, partials_removed_on_error, staging_dir

    with pytest.raises(LayercamError, match="full"):
        with partials_removed_on_error(tmp_path):
            done = staging_dir(tmp_path, "a")
            (done / "a.png").write_bytes(b"a")
            commit_staged(done, tmp_path, ["a.png"])
            half = staging_dir(tmp_path, "b")
            (half / "b0.png").write_bytes(b"b")
            raise LayercamError("cannot write b1.png (the disk is full)")
    assert sorted(os.listdir(tmp_path)) == ["a.png"]
    with partials_removed_on_error(tmp_path):
        (staging_dir(tmp_path, "c") / "c.png").write_bytes(b"c")
    assert (tmp_path / ".partial-c" / "c.png").exists()


