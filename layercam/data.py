"""Pixel sampling: random ``(x, y, t)`` with target colours and flow correspondences, all tensors."""

from __future__ import annotations

import numpy as np
import torch


def normalise_xy(x: torch.Tensor, y: torch.Tensor, w: int, h: int) -> torch.Tensor:
    """Pixel coordinates (centres at integer + 0.5 convention) -> ``(N, 2)`` in ``[-1, 1]``."""
    return torch.stack([(x + 0.5) / w * 2 - 1, (y + 0.5) / h * 2 - 1], dim=1)


def pixel_grid(h: int, w: int, device="cpu") -> torch.Tensor:
    """All pixel centres of an ``h x w`` frame, row-major, as ``(h*w, 2)`` normalised coordinates."""
    ys, xs = torch.meshgrid(torch.arange(h, device=device, dtype=torch.float32), torch.arange(w, device=device, dtype=torch.float32), indexing="ij")
    return normalise_xy(xs.flatten(), ys.flatten(), w, h)


class PixelSampler:
    """Holds a clip as tensors and draws batches.

    ``frames (T, H, W, 3)`` float in ``[0, 1]``; ``fw``/``bw`` ``(T-1, H, W, 2)`` flows (pixels, x-y
    order) and ``fw_ok``/``bw_ok`` ``(T-1, H, W)`` consistency masks, or None. ``masks (T, H, W)``
    optional foreground masks for alpha bootstrapping.
    """

    def __init__(self, frames: np.ndarray, fw=None, bw=None, fw_ok=None, bw_ok=None, masks=None, device="cpu", seed: int = 0):
        if frames.ndim != 4 or frames.shape[-1] != 3:
            raise ValueError(f"frames must be (T, H, W, 3), got {frames.shape}")
        self.device = torch.device(device)
        self.frames = torch.as_tensor(np.ascontiguousarray(frames), dtype=torch.float32, device=self.device)
        self.T, self.H, self.W = frames.shape[:3]
        self.has_flow = fw is not None and self.T > 1 and len(fw) == self.T - 1
        if self.has_flow:
            to = lambda a, dt: torch.as_tensor(np.ascontiguousarray(a), dtype=dt, device=self.device)
            self.fw, self.bw = to(fw, torch.float32), to(bw, torch.float32)
            self.fw_ok = to(fw_ok, torch.bool) if fw_ok is not None else torch.ones(self.fw.shape[:3], dtype=torch.bool, device=self.device)
            self.bw_ok = to(bw_ok, torch.bool) if bw_ok is not None else torch.ones(self.bw.shape[:3], dtype=torch.bool, device=self.device)
        self.masks = torch.as_tensor(masks, dtype=torch.float32, device=self.device) if masks is not None else None
        # the generator lives where the data does, so that a batch is drawn without host transfers
        self.seed, self.draws = int(seed), 0
        self.gen = torch.Generator(device=self.device).manual_seed(self.seed)

    def state_dict(self) -> dict:
        return {"gen": self.gen.get_state(), "seed": self.seed, "draws": self.draws}

    def load_state_dict(self, s: dict) -> None:
        """Continues the saved stream. A state saved by another stream (another data-parallel
        rank's seed) or on another device type reseeds this one deterministically instead."""
        self.draws = int(s.get("draws", 0))
        if s.get("seed", self.seed) == self.seed:
            try:
                self.gen.set_state(s["gen"])
                return
            except RuntimeError:  # e.g. a CUDA generator state loaded on the CPU
                pass
        self.gen.manual_seed(self.seed + 7919 * self.draws)

    def sample(self, n: int) -> dict:
        g = self.gen
        self.draws += 1
        dev = self.device
        t = torch.randint(0, self.T, (n,), generator=g, device=dev)
        y = torch.randint(0, self.H, (n,), generator=g, device=dev)
        x = torch.randint(0, self.W, (n,), generator=g, device=dev)
        batch = {
            "t": t,
            "xy": normalise_xy(x.float(), y.float(), self.W, self.H),
            "rgb": self.frames[t, y, x],
        }
        if self.masks is not None:
            batch["mask"] = self.masks[t, y, x]
        if self.has_flow:
            forward = torch.rand(n, generator=g, device=dev) < 0.5
            forward = torch.where(t == self.T - 1, torch.zeros_like(forward), forward)
            forward = torch.where(t == 0, torch.ones_like(forward), forward)
            ti = torch.where(forward, t, t - 1).clamp(0, self.T - 2)
            f = torch.where(forward[:, None], self.fw[ti, y, x], self.bw[ti, y, x])
            ok = torch.where(forward, self.fw_ok[ti, y, x], self.bw_ok[ti, y, x])
            t2 = torch.where(forward, t + 1, t - 1)
            x2, y2 = x.float() + f[:, 0], y.float() + f[:, 1]
            inside = (x2 >= 0) & (x2 <= self.W - 1) & (y2 >= 0) & (y2 <= self.H - 1)
            batch.update(t_match=t2, xy_match=normalise_xy(x2, y2, self.W, self.H), match_ok=ok & inside)
        return batch
