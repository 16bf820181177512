"""The pixel sampler reads a batch's pixels from where the clip is kept (frames in memory or on
disk; flows in float16, possibly at a working resolution below the frames') and gives the values a
float32 copy of everything would."""

from __future__ import annotations

import numpy as np
import torch

from layercam.engine.sampler import PixelSampler


def test_8bit_frames_read_back_exactly():
    levels = (np.arange(256, dtype=np.float64) / 255.0).astype(np.float32)  # as the clip loaders make them
    frames = np.broadcast_to(levels[None, :, None, None], (2, 256, 4, 3)).copy()
    s = PixelSampler(frames)
    t = torch.zeros(256, dtype=torch.long)
    y = torch.arange(256)
    assert torch.equal(s.colours(t, y, torch.zeros_like(y)), torch.from_numpy(frames[0, :, 0]))


def test_frames_and_flow_on_disk_are_gathered_not_loaded(tmp_path):
    """A clip kept on disk (uint8 frames, float16 flows) gives the values of its float32 copy, and
    the sampler holds no copy of it."""
    from layercam.io.frames import DiskArray, Frames

    rng = np.random.default_rng(0)
    u8 = rng.integers(0, 256, (3, 5, 6, 3), dtype=np.uint8)
    raw = DiskArray.create(tmp_path / "f.raw", np.uint8, u8.shape)
    raw[0:3] = u8
    fw = DiskArray.create(tmp_path / "fw.raw", np.float16, (2, 5, 6, 2))
    fw[0:2] = rng.normal(size=(2, 5, 6, 2))
    frames = Frames(raw)
    s = PixelSampler(frames, fw, fw)
    assert s.frames is frames and s.fw is fw
    t, y, x = torch.tensor([0, 2, 1]), torch.tensor([4, 0, 2]), torch.tensor([5, 1, 3])
    assert torch.equal(s.colours(t, y, x), torch.from_numpy(u8[t, y, x].astype(np.float32) / np.float32(255)))
    f, ok = s.flow_at(torch.tensor([0, 1, 1]), y, x, torch.ones(3, dtype=torch.bool))
    assert torch.equal(f, torch.from_numpy(np.asarray(fw)[[0, 1, 1], y, x].astype(np.float32))) and ok.all()
    assert s.sample(16)["rgb"].shape == (16, 3)


def test_flow_at_a_working_resolution_is_read_in_frame_pixels():
    """A flow computed at half size (in its own pixels) reads as the full-size flow would."""
    T, H, W = 3, 8, 12
    frames = np.zeros((T, H, W, 3), np.float32)
    yy, xx = np.mgrid[0:H // 2, 0:W // 2].astype(np.float32)
    half = np.stack([0.25 * xx + 1.0, np.full_like(xx, -0.5)], -1)  # half-size pixels
    fw = np.stack([half] * (T - 1)).astype(np.float16)
    s = PixelSampler(frames, fw, -fw)
    y = torch.tensor([0, 3, 7])
    x = torch.tensor([0, 5, 11])
    f, ok = s.flow_at(torch.zeros(3, dtype=torch.long), y, x, torch.ones(3, dtype=torch.bool))
    want = np.stack([half[y.numpy() // 2, x.numpy() // 2, 0] * 2, half[y.numpy() // 2, x.numpy() // 2, 1] * 2], -1)
    assert np.allclose(f.numpy(), want) and ok.all()
    b = s.sample(64)
    assert b["rgb"].dtype == torch.float32 and b["xy_match"].dtype == torch.float32
