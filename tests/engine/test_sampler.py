"""The pixel sampler holds a clip compactly (8-bit frames as uint8, others as float16; flows in
float16, possibly at a working resolution below the frames') and gives the values a float32 copy
of everything would."""

from __future__ import annotations

import numpy as np
import torch

from layercam.engine.sampler import PixelSampler, compact_frames


def test_8bit_frames_are_held_as_uint8_and_read_back_exactly():
    levels = (np.arange(256, dtype=np.float64) / 255.0).astype(np.float32)  # as the clip loaders make them
    frames = np.broadcast_to(levels[None, :, None, None], (2, 256, 4, 3)).copy()
    s = PixelSampler(frames)
    assert s.frames.dtype == torch.uint8
    t = torch.zeros(256, dtype=torch.long)
    y = torch.arange(256)
    assert torch.equal(s.colours(t, y, torch.zeros_like(y)), torch.from_numpy(frames[0, :, 0]))


def test_other_frames_are_held_as_float16():
    frames = np.random.default_rng(0).random((2, 5, 6, 3), dtype=np.float32)
    packed = compact_frames(frames)
    assert packed.dtype == np.float16 and np.abs(packed - frames).max() < 1e-3
    assert PixelSampler(frames).frames.dtype == torch.float16


def test_flow_at_a_working_resolution_is_read_in_frame_pixels():
    """A flow computed at half size (in its own pixels) reads as the full-size flow would."""
    T, H, W = 3, 8, 12
    frames = np.zeros((T, H, W, 3), np.float32)
    yy, xx = np.mgrid[0:H // 2, 0:W // 2].astype(np.float32)
    half = np.stack([0.25 * xx + 1.0, np.full_like(xx, -0.5)], -1)  # half-size pixels
    fw = np.stack([half] * (T - 1)).astype(np.float16)
    s = PixelSampler(frames, fw, -fw)
    assert s.fw.dtype == torch.float16
    y = torch.tensor([0, 3, 7])
    x = torch.tensor([0, 5, 11])
    f, ok = s.flow_at(torch.zeros(3, dtype=torch.long), y, x, torch.ones(3, dtype=torch.bool))
    want = np.stack([half[y.numpy() // 2, x.numpy() // 2, 0] * 2, half[y.numpy() // 2, x.numpy() // 2, 1] * 2], -1)
    assert np.allclose(f.numpy(), want) and ok.all()
    b = s.sample(64)
    assert b["rgb"].dtype == torch.float32 and b["xy_match"].dtype == torch.float32
