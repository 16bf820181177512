"""Tests of layercam.io.masks: ordering, frame matching, resizing, thresholding, errors, real data."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from layercam.core.errors import LayercamError
from layercam.io import Clip, load_clip
from layercam.io.masks import list_masks, load_masks

from conftest import SHARED_DATA as DATA  # $LAYERCAM_DATA, else beside the checkout
LIBBY = DATA / "layers_davis_libby"


def clip_of(t: int, h: int = 6, w: int = 8, frame_indices=None) -> Clip:
    meta = {} if frame_indices is None else {"frame_indices": list(frame_indices)}
    return Clip(frames=np.zeros((t, h, w, 3), np.float32), source="test", names=[str(i) for i in range(t)], meta=meta)


def square(i: int, h: int = 6, w: int = 8, level: int = 255) -> np.ndarray:
    """Mask number ``i``: a 2x2 square whose column encodes ``i`` (so order can be checked)."""
    m = np.zeros((h, w), np.uint8)
    m[1:3, i % (w - 1) : i % (w - 1) + 2] = level
    return m


def write(folder: Path, names, imgs) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for n, im in zip(names, imgs):
        assert cv2.imwrite(str(folder / n), im)


def column(mask: np.ndarray) -> int:
    return int(np.argwhere(mask > 0)[:, 1].min())


def test_natural_order_and_binary(tmp_path):
    names = ["m1.png", "m2.png", "m10.png"]  # lexical order would put m10 second
    write(tmp_path, names, [square(i) for i in (1, 2, 3)])
    (tmp_path / "notes.txt").write_text("ignored")
    (tmp_path / ".hidden.png").write_bytes(b"")
    assert [p.name for p in list_masks(tmp_path)] == names
    m = load_masks(tmp_path, clip_of(3))
    assert m.shape == (3, 6, 8) and m.dtype == np.float32
    assert set(np.unique(m)) == {0.0, 1.0}
    assert [column(x) for x in m] == [1, 2, 3]
    assert m[0].sum() == 4


def test_zero_one_levels(tmp_path):
    write(tmp_path, ["a.png", "b.png"], [square(0, level=1), np.zeros((6, 8), np.uint8)])
    m = load_masks(tmp_path, clip_of(2))
    assert m[0].sum() == 4 and m[1].sum() == 0  # a frame without the object stays empty


def test_all_empty(tmp_path):
    write(tmp_path, ["a.png"], [np.zeros((6, 8), np.uint8)])
    assert load_masks(tmp_path, clip_of(1)).sum() == 0


def test_colour_and_alpha_masks(tmp_path):
    rgb = np.zeros((6, 8, 3), np.uint8)
    rgb[1:3, 1:3, 2] = 200  # red only (BGR on disk)
    rgb[4, 4, 1] = 128  # another object, green
    rgba = np.zeros((6, 8, 4), np.uint8)
    rgba[2:4, 5:7, 3] = 255  # mask stored in alpha only
    write(tmp_path, ["0.png", "1.png"], [rgb, rgba])
    m = load_masks(tmp_path, clip_of(2))
    assert m[0].sum() == 5 and m[0][4, 4] == 1
    assert m[1].sum() == 4 and m[1][2, 5] == 1


def test_resize_keeps_the_layout(tmp_path):
    big = np.kron(square(2), np.ones((4, 4), np.uint8))  # 24x32, same layout
    write(tmp_path, ["0.png"], [big])
    m = load_masks(tmp_path, clip_of(1))
    assert m.shape == (1, 6, 8)
    assert np.array_equal(m[0], (square(2) > 0).astype(np.float32))


def test_masks_land_on_the_frames_pixels(tmp_path):
    """A shrunk mask is resampled as the frames are: a pixel is object where most of its area is (nearest
    neighbour takes each cell's top-left source pixel, a third of a pixel off at 1/3, and keeps lines
    thinner than a pixel whole wherever one crosses that pixel)."""
    src = np.zeros((36, 48), np.uint8)
    src[6:30, 13:22] = 255  # columns 13-21: two thirds of cell 4 (12-14), all of 5-6, one third of 7 (21-23)
    src[:, 30] = 255  # a line one source pixel wide, on the top-left pixel of cell 10
    frame = np.repeat(src[..., None], 3, axis=2)
    write(tmp_path / "frames", ["0.png"], [frame])
    write(tmp_path / "masks", ["0.png"], [src])
    clip = load_clip(tmp_path / "frames", resize="16x12")
    m = load_masks(tmp_path / "masks", clip)[0] > 0
    assert np.array_equal(m, clip.frames[0, :, :, 0] > 0.5)  # the frame's own pixels, at 0.5 of its level
    assert m[5, 4:7].all() and not m[5, 7] and not m[:, 10].any()


def test_jpeg_masks_threshold_noise(tmp_path):
    big = np.kron(square(2), np.ones((8, 8), np.uint8))
    write(tmp_path, ["0.jpg"], [big])
    m = load_masks(tmp_path, clip_of(1, 48, 64))
    assert set(np.unique(m)) <= {0.0, 1.0}
    assert abs(m.sum() - (big > 0).sum()) <= 16  # compression ringing stays below half level


def test_more_masks_than_frames(tmp_path):
    write(tmp_path, [f"{i:05d}.png" for i in range(6)], [square(i) for i in range(6)])
    strided = load_masks(tmp_path, clip_of(3, frame_indices=[0, 2, 4]))
    assert [column(x) for x in strided] == [0, 2, 4]
    first = load_masks(tmp_path, clip_of(3))  # no frame indices known: the first T
    assert [column(x) for x in first] == [0, 1, 2]
    exact = load_masks(tmp_path, clip_of(6, frame_indices=[0, 2, 4, 6, 8, 10]))  # already matched
    assert [column(x) for x in exact] == [0, 1, 2, 3, 4, 5]
    with pytest.raises(LayercamError, match="source frame 9"):
        load_masks(tmp_path, clip_of(4, frame_indices=[0, 3, 6, 9]))


def _one_line(e: pytest.ExceptionInfo) -> str:
    msg = str(e.value)
    assert "\n" not in msg
    return msg


def test_errors(tmp_path):
    with pytest.raises(LayercamError, match="not found") as e:
        load_masks(tmp_path / "nope", clip_of(1))
    _one_line(e)
    f = tmp_path / "file.png"
    f.write_bytes(b"x")
    with pytest.raises(LayercamError, match="folder"):
        load_masks(f, clip_of(1))
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "readme.txt").write_text("no masks")
    with pytest.raises(LayercamError, match="no images") as e:
        load_masks(empty, clip_of(1))
    _one_line(e)
    few = tmp_path / "few"
    write(few, ["0.png", "1.png"], [square(0), square(1)])
    with pytest.raises(LayercamError, match="2 masks but the clip has 3 frames") as e:
        load_masks(few, clip_of(3))
    _one_line(e)
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "0.png").write_bytes(b"not a png")
    with pytest.raises(LayercamError, match="cannot decode"):
        load_masks(bad, clip_of(1))


@pytest.mark.data
@pytest.mark.skipif(not (LIBBY / "masks_gt").is_dir(), reason=f"{LIBBY} is absent")
def test_davis_libby_masks():
    clip = load_clip(LIBBY / "frames", max_frames=3, stride=2, resize=0.25)
    m = load_masks(LIBBY / "masks_gt", clip)
    assert m.shape == (3, clip.H, clip.W) == (3, 120, 214)
    assert set(np.unique(m)) == {0.0, 1.0}
    frac = m.mean(axis=(1, 2))
    assert ((frac > 0.005) & (frac < 0.5)).all()  # the dog: present, not the whole frame
    ref = cv2.imread(str(LIBBY / "masks_gt" / "00004.png"), cv2.IMREAD_GRAYSCALE)  # frame index 4
    ref = cv2.resize(ref / 255.0, (clip.W, clip.H), interpolation=cv2.INTER_AREA) > 0.5  # as the frames are
    assert np.array_equal(m[2] > 0, ref)
    assert not np.array_equal(m[0], m[2])  # the dog moves
