"""Pixel sampling: random ``(x, y, t)`` with target colours and flow correspondences, all tensors,
read pixel by pixel from where the clip is kept (memory or disk)."""

from __future__ import annotations

import numpy as np
import torch

from layercam.scene.coords import normalise_xy

PROBES = 256  # rows of a batch's "probe" draws
PROBE_SEED = 104729  # their stream's seed, from the sampler's


def _host(a, kind: str):
    """An array the sampler gathers from: a :class:`~layercam.io.frames.DiskArray` or an ndarray as
    it is (no copy), anything else (a tensor, a list) as an ndarray."""
    from layercam.io.frames import DiskArray

    if a is None or isinstance(a, DiskArray) or isinstance(a, np.ndarray):
        return a
    if isinstance(a, torch.Tensor):
        return a.detach().cpu().numpy()
    arr = np.asarray(a)
    if arr.dtype == object:
        raise ValueError(f"{kind}: expected an array")
    return arr


class PixelSampler:
    """Draws batches of pixels of a clip, reading only those pixels from where the clip is kept.

    ``frames (T, H, W, 3)`` in ``[0, 1]``: a :class:`~layercam.io.frames.Frames` (a clip's frames,
    in memory or on disk) or an ndarray; ``fw``/``bw`` ``(T-1, h, w, 2)`` flows (pixels of their
    own grid, x-y order) and ``fw_ok``/``bw_ok`` ``(T-1, h, w)`` consistency masks, or None
    (ndarrays or the flow stage's :class:`~layercam.io.frames.DiskArray`): ``h x w`` may be a
    working resolution below the frames' (the flow is then read at the nearest flow pixel and
    scaled to frame pixels). ``masks (T, H, W)`` optional foreground masks for alpha bootstrapping.
    Pixels are drawn on ``device`` and read on the host (a gather through each file's memory map,
    whose pages are given back at once), then moved to ``device`` as float32: memory is the batch's,
    whatever the clip's length. Every random number a training step uses comes from this sampler's
    two generators (pixels, and a batch's ``probe`` draws for the model's regularisers), so their
    state is all a resume needs.
    """

    def __init__(self, frames, fw=None, bw=None, fw_ok=None, bw_ok=None, masks=None, device="cpu", seed: int = 0):
        from layercam.io.frames import Frames

        if len(frames.shape) != 4 or frames.shape[-1] != 3:
            raise ValueError(f"frames must be (T, H, W, 3), got {tuple(frames.shape)}")
        self.device = torch.device(device)
        self.frames = frames if isinstance(frames, Frames) else Frames(_host(frames, "frames"))
        self.T, self.H, self.W = (int(v) for v in frames.shape[:3])
        self.has_flow = fw is not None and self.T > 1 and len(fw) == self.T - 1
        if self.has_flow:
            self.fw, self.bw = _host(fw, "fw"), _host(bw, "bw")
            self.fh, self.fwid = (int(v) for v in self.fw.shape[1:3])
            self.fw_ok, self.bw_ok = _host(fw_ok, "fw_ok"), _host(bw_ok, "bw_ok")
        self.masks = _host(masks, "masks")
        # the generator lives where the data does, so that a batch is drawn without host transfers
        self.seed, self.draws = int(seed), 0
        self.gen = torch.Generator(device=self.device).manual_seed(self.seed)
        self.probe_gen = torch.Generator(device=self.device).manual_seed(self.seed + PROBE_SEED)

    def _gather(self, a, *idx: torch.Tensor, dtype=torch.float32) -> torch.Tensor:
        from layercam.io.frames import gather

        host = [i.cpu().numpy() for i in idx]
        return torch.from_numpy(np.ascontiguousarray(gather(a, *host))).to(device=self.device, dtype=dtype)

    def state_dict(self) -> dict:
        return {"gen": self.gen.get_state(), "probe_gen": self.probe_gen.get_state(),
                "seed": self.seed, "draws": self.draws}

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
        host = [i.cpu().numpy() for i in (t, y, x)]
        return torch.from_numpy(np.ascontiguousarray(self.frames.gather(*host))).to(self.device)

    def flow_at(self, ti: torch.Tensor, y: torch.Tensor, x: torch.Tensor,
                forward: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Flow of pair ``ti`` at frame pixels ``(x, y)``, forward or backward: ``(N, 2)`` in frame
        pixels and the consistency flag ``(N,)``; read at the nearest pixel of the flow's grid."""
        if (self.fh, self.fwid) == (self.H, self.W):
            fy, fx = y, x
        else:
            fy = ((y.float() + 0.5) * (self.fh / self.H)).long().clamp_(0, self.fh - 1)
            fx = ((x.float() + 0.5) * (self.fwid / self.W)).long().clamp_(0, self.fwid - 1)
        f = torch.where(forward[:, None], self._gather(self.fw, ti, fy, fx), self._gather(self.bw, ti, fy, fx))
        if (self.fh, self.fwid) != (self.H, self.W):
            f = f * torch.tensor([self.W / self.fwid, self.H / self.fh], device=f.device)
        if self.fw_ok is None:
            return f, torch.ones(len(ti), dtype=torch.bool, device=f.device)
        return f, torch.where(forward, self._gather(self.fw_ok, ti, fy, fx, dtype=torch.bool),
                              self._gather(self.bw_ok, ti, fy, fx, dtype=torch.bool))

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
            batch["mask"] = self._gather(self.masks, t, y, x)
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
