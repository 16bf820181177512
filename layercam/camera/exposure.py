"""Per-frame exposure ``log2 dt``: given, one learned offset per phase, or a learned latent per frame."""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from layercam.scene.encodings import gather_rows

EV_BOUND = 24.0  # guard: learned exposures stay within +-24 stops of their start


class ExposureField(nn.Module):
    """``t (N,) -> log2 dt (N, 1)``.

    learn "none": the given values. "ratio": one learned offset per phase (phase 0 fixed), for
    alternating exposures without a known step. "all": a learned offset per frame (frame 0 fixed,
    which removes the scale ambiguity between irradiance and exposure). Offsets are bounded with a
    scaled tanh to +-``EV_BOUND`` stops.
    """

    def __init__(self, log2_dt: np.ndarray, learn: str = "none", phase: np.ndarray | None = None):
        super().__init__()
        self.register_buffer("init", torch.as_tensor(np.asarray(log2_dt, dtype=np.float32)))
        self.learn = learn
        n = len(log2_dt)
        if learn == "none":
            self.register_buffer("index", torch.zeros(n, dtype=torch.long))
            self.delta = None
            return
        if learn == "ratio":
            if phase is None:
                raise ValueError("learn='ratio' needs a phase per frame")
            index = torch.as_tensor(np.asarray(phase), dtype=torch.long)
        elif learn == "all":
            index = torch.arange(n)
        else:
            raise ValueError(f"unknown exposure learning mode {learn!r}")
        self.register_buffer("index", index)
        self.delta = nn.Parameter(torch.zeros(int(index.max()) + 1))

    def values(self) -> torch.Tensor:
        """``(T,)`` current log2 exposure of every frame."""
        if self.delta is None:
            return self.init
        d = self.delta.clone()
        d = torch.cat([torch.zeros_like(d[:1]), d[1:]])  # the first phase / frame is the reference
        return self.init + EV_BOUND * torch.tanh(gather_rows(d, self.index) / EV_BOUND)

    def reference(self) -> float:
        """The clip's reference exposure: the median log2 exposure of its frames (what ``layercam
        render`` counts stops from, and the exposure of the atlas PNGs that ``edit`` reads back)."""
        return float(np.median(self.values().detach().float().cpu().numpy()))

    def forward(self, t: torch.Tensor) -> torch.Tensor:
        return gather_rows(self.values(), t)[:, None]  # (a deterministic backward: gather_rows)
