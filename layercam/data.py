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


def compact_frames(frames: np.ndarray) -> np.ndarray:
    """Frames ``(T, H, W, 3)`` in ``[0, 1]`` as the sampler holds them: ``uint8`` when every value is
    an 8-bit level (``k / 255`` to within float32 rounding), else ``float16`` (a quarter or half of
    float32; converted one frame at a time, so no float32 copy of the clip is made)."""
    if frames.dtype == np.uint8:
        return frames
    out = np.empty(frames.shape, np.uint8)
    for t in range(frames.shape[0]):
        q = np.rint(frames[t] * 255.0)
        if np.abs(q / np.float32(255.0) - frames[t]).max(initial=0.0) > 1e-6:
            return np.stack([f.astype(np.float16) for f in frames])
        out[t] = q
    return out


PROBES = 256  # rows of a batch's "probe" draws
PROBE_SEED = 104729  # their stream's seed, from the sampler's


class PixelSampler:
    """Holds a clip compactly and draws batches.

    ``frames (T, H, W, 3)`` in ``[0, 1]`` (kept as uint8 or float16, :func:`compact_frames`);
    ``fw``/``bw`` ``(T-1, h, w, 2)`` flows (pixels of their own grid, x-y order) and ``fw_ok``/
    ``bw_ok`` ``(T-1, h, w)`` consistency masks, or None: ``h x w`` may be a working resolution
    below the frames' (the flow is then read at the nearest flow pixel and scaled to frame pixels),
    kept in float16. ``masks (T, H, W)`` optional foreground masks for alpha bootstrapping;
    Every random number a training step uses comes from this sampler's two generators (pixels, and
    a batch's ``probe`` draws for the model's regularisers), so their state is all a resume needs.
    A batch is converted to float32; memory is that of the compact arrays, whatever the batch.
    """

    def __init__(self, frames: np.ndarray, fw=None, bw=None, fw_ok=None, bw_ok=None, masks=None, device="cpu", seed: int = 0):
        if frames.ndim != 4 or frames.shape[-1] != 3:
            raise ValueError(f"frames must be (T, H, W, 3), got {frames.shape}")
        self.device = torch.device(device)
        to = lambda a, dt: torch.as_tensor(np.ascontiguousarray(a), dtype=dt, device=self.device)  # noqa: E731
        packed = compact_frames(frames)
        self.frames = to(packed, torch.uint8 if packed.dtype == np.uint8 else torch.float16)
        self.T, self.H, self.W = frames.shape[:3]
        self.has_flow = fw is not None and self.T > 1 and len(fw) == self.T - 1
        if self.has_flow:
            self.fw, self.bw = to(fw, torch.float16), to(bw, torch.float16)
            self.fh, self.fwid = self.fw.shape[1:3]
            self.fw_ok = to(fw_ok, torch.bool) if fw_ok is not None else torch.ones(self.fw.shape[:3], dtype=torch.bool, device=self.device)
            self.bw_ok = to(bw_ok, torch.bool) if bw_ok is not None else torch.ones(self.bw.shape[:3], dtype=torch.bool, device=self.device)
        self.masks = to(masks, torch.float16) if masks is not None else None
        # the generator lives where the data does, so that a batch is drawn without host transfers
        self.seed, self.draws = int(seed), 0
        self.gen = torch.Generator(device=self.device).manual_seed(self.seed)
        self.probe_gen = torch.Generator(device=self.device).manual_seed(self.seed + PROBE_SEED)

    def state_dict(self) -> dict:
        return {"gen": self.gen.get_state(), "probe_gen": self.probe_gen.get_state(), "seed": self.seed, "draws": self.draws}

    def load_state_dict(self, s: dict) -> None:
        """Continues the saved stream. A state saved by another stream (another data-parallel
        rank's seed) or on another device type reseeds this one deterministically instead."""
        self.draws = int(s.get("draws", 0))
        if s.get("seed", self.seed) == self.seed and "probe_gen" in s:
            try:
                self.gen.set_state(s["gen"])
                self.probe_gen.set_state(s["probe_gen"])
                return
            except RuntimeError:  # e.g. a CUDA generator state loaded on the CPU
                pass
        self.gen.manual_seed(self.seed + 7919 * self.draws)
        self.probe_gen.manual_seed(self.seed + PROBE_SEED + 7919 * self.draws)

    def colours(self, t: torch.Tensor, y: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """Frame values at integer pixels -> ``(N, 3)`` float32 in ``[0, 1]``."""
        v = self.frames[t, y, x]
        return v.float() / 255.0 if v.dtype == torch.uint8 else v.float()

    def flow_at(self, ti: torch.Tensor, y: torch.Tensor, x: torch.Tensor, forward: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Flow of pair ``ti`` at frame pixels ``(x, y)``, forward or backward: ``(N, 2)`` in frame
        pixels and the consistency flag ``(N,)``; read at the nearest pixel of the flow's grid."""
        if (self.fh, self.fwid) == (self.H, self.W):
            fy, fx = y, x
        else:
            fy = ((y.float() + 0.5) * (self.fh / self.H)).long().clamp_(0, self.fh - 1)
            fx = ((x.float() + 0.5) * (self.fwid / self.W)).long().clamp_(0, self.fwid - 1)
        f = torch.where(forward[:, None], self.fw[ti, fy, fx], self.bw[ti, fy, fx]).float()
        if (self.fh, self.fwid) != (self.H, self.W):
            f = f * torch.tensor([self.W / self.fwid, self.H / self.fh], device=f.device)
        return f, torch.where(forward, self.fw_ok[ti, fy, fx], self.bw_ok[ti, fy, fx])

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
            "rgb": self.colours(t, y, x),
        }
        if self.masks is not None:
            batch["mask"] = self.masks[t, y, x].float()
        # uniform draws for the model's own regularisers (the tone mapper's monotonicity probe),
        # from a second stream saved with the first (a resumed run draws what an uninterrupted one
        # would); a stream of their own leaves the pixels drawn as they were before they existed
        batch["probe"] = torch.rand(PROBES, 3, generator=self.probe_gen, device=dev)
        if self.has_flow:
            forward = torch.rand(n, generator=g, device=dev) < 0.5
            forward = torch.where(t == self.T - 1, torch.zeros_like(forward), forward)
            forward = torch.where(t == 0, torch.ones_like(forward), forward)
            ti = torch.where(forward, t, t - 1).clamp(0, self.T - 2)
            f, ok = self.flow_at(ti, y, x, forward)
            t2 = torch.where(forward, t + 1, t - 1)
            x2, y2 = x.float() + f[:, 0], y.float() + f[:, 1]
            inside = (x2 >= 0) & (x2 <= self.W - 1) & (y2 >= 0) & (y2 <= self.H - 1)
            batch.update(t_match=t2, xy_match=normalise_xy(x2, y2, self.W, self.H), match_ok=ok & inside)
        return batch
