"""Tone mapper (paper Sec. 3.3): ``c = T(log2 r' + log2 dt)``, three per-channel MLPs.

The three channel MLPs are evaluated as one batched op (``torch.baddbmm`` over a channel axis).
:func:`srgb_tone` is the fixed curve used when a clip has a single exposure and no CRF can be learned.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from layercam.core.colour import srgb_decode, srgb_encode_torch
from layercam.scene.encodings import gather_rows

Z_SCALE = 0.125  # MLP input is z / 8: log exposures span about +-20 stops
LUT_RANGE = 32.0  # the lookup-table fast path covers +-32 stops; beyond, the curve is flat


def srgb_tone(z: torch.Tensor) -> torch.Tensor:
    """Fixed tone curve: sRGB of ``2^z`` clipped to 1. ``z (N, 3) -> c (N, 3)``."""
    return srgb_encode_torch(torch.exp2(z.clamp(-40, 1)))


class ToneMapper(nn.Module):
    """``z (N, 3) -> c (N, 3)`` in ``(0, 1)``; channel ``k`` of ``z`` goes through MLP ``k`` (its
    slope is kept positive by the paper's gradient loss, :func:`layercam.engine.losses.gradient_loss`).
    ``lut`` > 0: evaluated on that many knots and interpolated (:meth:`_lut_logits`)."""

    def __init__(self, width: int = 64, depth: int = 2, lut: int = 0):
        super().__init__()
        self.lut = lut
        dims = [1] + [width] * depth + [1]
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        for a, b in zip(dims[:-1], dims[1:]):
            w = torch.empty(3, a, b)
            for k in range(3):
                nn.init.kaiming_uniform_(w[k].T, a=math.sqrt(5))
            bound = 1 / math.sqrt(a)
            self.weights.append(nn.Parameter(w))
            self.biases.append(nn.Parameter(torch.empty(3, 1, b).uniform_(-bound, bound)))

    def logits(self, z: torch.Tensor) -> torch.Tensor:
        """Pre-sigmoid output ``(N, 3)``."""
        if z.ndim != 2 or z.shape[1] != 3:
            raise ValueError(f"ToneMapper expects z of shape (N, 3), got {tuple(z.shape)}")
        z = z.float()
        x = (z * Z_SCALE).t().unsqueeze(-1)  # (3, N, 1)
        n = len(self.weights)
        for i, (w, b) in enumerate(zip(self.weights, self.biases)):
            x = torch.baddbmm(b, x, w)
            if i < n - 1:
                x = torch.relu(x)
        return x.squeeze(-1).t()

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        # the curve runs in float32 even under autocast: bf16 would quantise it to ~2^-9
        with torch.autocast(z.device.type, enabled=False):
            if self.lut and z.shape[0] > self.lut:
                return torch.sigmoid(self._lut_logits(z))
            return torch.sigmoid(self.logits(z))

    def _lut_logits(self, z: torch.Tensor) -> torch.Tensor:
        """Fast path: evaluate the MLPs on ``lut`` knots over ``[-LUT_RANGE, LUT_RANGE]`` stops and
        interpolate linearly (differentiable in the knot values, so the MLPs still learn). The
        curves are 1D, so this is exact to the interpolation error (< 1e-4 at 1024 knots)."""
        k = torch.linspace(-LUT_RANGE, LUT_RANGE, self.lut, device=z.device)
        table = self.logits(k[:, None].expand(-1, 3).contiguous())  # (K, 3)
        zf = z.float().clamp(-LUT_RANGE, LUT_RANGE)
        pos = (zf + LUT_RANGE) / (2 * LUT_RANGE) * (self.lut - 1)
        i0 = pos.floor().long().clamp(0, self.lut - 2)
        frac = pos - i0.float()
        lo = torch.gather(table, 0, i0)
        hi = torch.gather(table, 0, i0 + 1)
        return lo + frac * (hi - lo)

    @torch.no_grad()
    def curve(self, z: torch.Tensor) -> torch.Tensor:
        """The response per channel on a 1D grid ``z (K,)`` -> ``(K, 3)``."""
        return self(z[:, None].expand(-1, 3).contiguous())


class FixedTone(nn.Module):
    """The fixed sRGB curve as a module (no parameters)."""

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return srgb_tone(z.float())

    @torch.no_grad()
    def curve(self, z: torch.Tensor) -> torch.Tensor:
        return self(z[:, None].expand(-1, 3).contiguous())


INIT_SLOPE = 1.0  # the learned curve's start sigmoid(INIT_SLOPE * ln2 * z) = r / (1 + r): it spans 4.2 stops from
                 # T = 0.5 to 0.95, where a real camera's shoulder is (a power 1/2.24 with a clip: 2.07)


def init_curve(z: torch.Tensor, slope: float = INIT_SLOPE) -> torch.Tensor:
    """The tone mapper's starting curve: ``sigmoid(slope * ln2 * z)``; ``T(0) = 0.5``."""
    return torch.sigmoid(slope * math.log(2) * z)


def initial_log2(frames: np.ndarray, log2_dt: np.ndarray, tone: str, slope: float = INIT_SLOPE) -> float:
    """The atlases' starting log2 irradiance: the median over the frames ``(T, H, W, 3)`` (grey,
    kept within 0.02..0.98) of their value through the inverse of the starting tone curve (the
    fixed sRGB curve, or :func:`init_curve` with ``slope``), less each frame's ``log2_dt (T,)``."""
    dt = np.asarray(log2_dt, dtype=np.float32)
    values, counts = [], []
    for t, f in enumerate(frames):  # a frame at a time: its distinct values and their counts, not the clip's pixels
        c = np.clip(f.mean(-1), 0.02, 0.98)
        zt = np.log2(np.maximum(srgb_decode(c), 1e-6)) if tone == "fixed" else np.log(c
            / (1 - c)) / (slope * math.log(2))
        v, k = np.unique((zt - dt[t]).astype(np.float32), return_counts=True)
        values.append(v)
        counts.append(k)
        if len(values) > 64:  # merged now and then: an 8-bit frame has at most 766 distinct values
            v, k = _merge(values, counts)
            values, counts = [v], [k]
    v, k = _merge(values, counts)
    return float(_weighted_median(v, k))


def _merge(values: list, counts: list) -> tuple[np.ndarray, np.ndarray]:
    v, inv = np.unique(np.concatenate(values), return_inverse=True)
    return v, np.bincount(inv, weights=np.concatenate(counts)).astype(np.int64)


def _weighted_median(v: np.ndarray, k: np.ndarray) -> np.float32:
    """``np.median`` of the float32 values ``v`` (sorted, distinct) each repeated ``k`` times."""
    n = int(k.sum())
    cum = np.cumsum(k)
    lo = v[np.searchsorted(cum, (n - 1) // 2, side="right")]
    hi = v[np.searchsorted(cum, n // 2, side="right")]
    return np.mean(np.array([lo, hi], np.float32))


def fit_init_curve(tone: ToneMapper, slope: float = INIT_SLOPE, steps: int = 300, seed: int = 0) -> float:
    """Fit ``tone`` to :func:`init_curve` over ``[-16, 16]`` stops; returns the final MSE."""
    g = torch.Generator().manual_seed(seed)
    opt = torch.optim.Adam(tone.parameters(), lr=1e-2)
    loss = torch.tensor(0.0)
    for _ in range(steps):
        z = (torch.rand(2048, 3, generator=g) * 32 - 16)
        loss = ((tone(z) - init_curve(z, slope)) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return float(loss.detach())
