"""The imaging model of the synthetic scenes and their result type: :class:`SynthScene`, the camera
response functions (``CRFS``), exposure with noise and 8-bit quantisation, and the checks and
clip shared by every family."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from layercam.core.colour import srgb_decode, srgb_encode
from layercam.core.errors import LayercamError
from layercam.io.clip import Clip


# --------------------------------------------------------------------------------------------
# Result type
# --------------------------------------------------------------------------------------------


@dataclass
class SynthScene:
    """A rendered synthetic scene and its ground truth.

    clip: LDR frames ``(T,H,W,3)`` float32, 8-bit quantised, in [0,1];
        ``clip.source == "synthetic:<family>"``.
    exposure_times: ``(T,)`` float64 relative exposure times (what a user would pass).
    hdr: ``(T,H,W,3)`` float32 linear sharp irradiance per frame (ground truth up to a
        per-channel scale).
    crf: name of the CRF used (see ``CRFS``).
    fg_mask: ``(T,H,W)`` bool foreground ground truth, or None.
    meta: family, parameters, ``gain``, geometry, blur kernels, focus settings...
    sharp_ldr: ``(T,H,W,3)`` noise-free sharp LDR ground truth (deblur families), or None.
    allfocus_hdr: ``(H,W,3)`` all-in-focus HDR (``mfme_stack``), or None.
    """

    clip: Clip
    exposure_times: np.ndarray
    hdr: np.ndarray
    crf: str
    fg_mask: np.ndarray | None = None
    meta: dict = field(default_factory=dict)
    sharp_ldr: np.ndarray | None = None
    allfocus_hdr: np.ndarray | None = None

    @property
    def frames(self) -> np.ndarray:
        """The LDR frames ``(T,H,W,3)`` (same as ``clip.frames``)."""
        return self.clip.frames


# --------------------------------------------------------------------------------------------
# Camera response functions
# --------------------------------------------------------------------------------------------

CRFS = ("gamma", "srgb", "scurve", "mixed")

_SCURVE_EPS = 1.0 / 1024.0
_SCURVE_DEFAULT = (1.2, float(np.log(0.10)))  # (slope a per natural-log unit, midpoint m)
_SCURVE_MIXED = (
    (1.05, float(np.log(0.08))),
    (1.2, float(np.log(0.10))),
    (1.35, float(np.log(0.13))),
)


def _sigmoid(u: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-u))


def _scurve(x: np.ndarray, a: float, m: float) -> np.ndarray:
    """Sigmoid in the log domain, normalised so that 0 -> 0 and 1 -> 1 (monotone, smooth)."""
    lo = _sigmoid(a * (np.log(_SCURVE_EPS) - m))
    hi = _sigmoid(a * (np.log(1.0 + _SCURVE_EPS) - m))
    return (_sigmoid(a * (np.log(x + _SCURVE_EPS) - m)) - lo) / (hi - lo)


def _scurve_inv(y: np.ndarray, a: float, m: float) -> np.ndarray:
    lo = _sigmoid(a * (np.log(_SCURVE_EPS) - m))
    hi = _sigmoid(a * (np.log(1.0 + _SCURVE_EPS) - m))
    s = np.clip(y * (hi - lo) + lo, 1e-12, 1.0 - 1e-12)
    return np.exp(m + np.log(s / (1.0 - s)) / a) - _SCURVE_EPS


def _check_crf(name: str) -> None:
    if name not in CRFS:
        raise LayercamError(f"unknown CRF {name!r}; choose one of {', '.join(CRFS)}")


def crf_apply(x: np.ndarray, name: str) -> np.ndarray:
    """Camera response: exposed linear values ``x`` (any shape; ``(...,3)`` for "mixed") are
    clipped to [0,1] and mapped to [0,1] pixel values. Names: ``CRFS``.

    "gamma": ``x**(1/2.2)``; "srgb": the sRGB transfer function; "scurve": a sigmoid in the
    log domain normalised to [0,1]; "mixed": slightly different S-curves per RGB channel.
    """
    _check_crf(name)
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    if name == "gamma":
        y = x ** (1.0 / 2.2)
    elif name == "srgb":
        y = srgb_encode(x)
    elif name == "scurve":
        y = _scurve(x, *_SCURVE_DEFAULT)
    else:
        if x.shape[-1] != 3:
            raise LayercamError(f"CRF 'mixed' needs (...,3) input, got shape {x.shape}")
        y = np.stack([_scurve(x[..., c], *_SCURVE_MIXED[c]) for c in range(3)], axis=-1)
    return np.clip(y, 0.0, 1.0).astype(np.float32)


def crf_inverse(y: np.ndarray, name: str) -> np.ndarray:
    """Inverse of ``crf_apply``: pixel values in [0,1] -> exposed linear values in [0,1]."""
    _check_crf(name)
    y = np.clip(np.asarray(y, dtype=np.float64), 0.0, 1.0)
    if name == "gamma":
        x = y**2.2
    elif name == "srgb":
        x = srgb_decode(y)
    elif name == "scurve":
        x = _scurve_inv(y, *_SCURVE_DEFAULT)
    else:
        if y.shape[-1] != 3:
            raise LayercamError(f"CRF 'mixed' needs (...,3) input, got shape {y.shape}")
        x = np.stack([_scurve_inv(y[..., c], *_SCURVE_MIXED[c]) for c in range(3)], axis=-1)
    return np.clip(x, 0.0, 1.0).astype(np.float32)


def _expose(
    irr: np.ndarray, t: float, gain: float, crf: str, noise: float, rng: np.random.Generator | None
) -> np.ndarray:
    """Irradiance ``(...,H,W,3)`` -> 8-bit-quantised LDR float32 (noise-free when rng is None)."""
    y = crf_apply(irr * (t * gain), crf)
    if rng is not None and noise > 0:
        y = y + rng.normal(0.0, noise, size=y.shape).astype(np.float32)
    return (np.round(np.clip(y, 0.0, 1.0) * 255.0) / 255.0).astype(np.float32)


def _check_common(frames: int, size, crf: str, noise: float) -> tuple[int, int]:
    if int(frames) < 1:
        raise LayercamError(f"frames must be >= 1, got {frames}")
    if len(size) != 2 or min(size) < 8:
        raise LayercamError(f"size must be (H, W) with both >= 8, got {size}")
    _check_crf(crf)
    if noise < 0:
        raise LayercamError(f"noise must be >= 0, got {noise}")
    return int(size[0]), int(size[1])


def _alternating(frames: int, ev_step: float) -> np.ndarray:
    return np.where(np.arange(frames) % 2 == 0, 1.0, 2.0**ev_step).astype(np.float64)


def _make_clip(frames: np.ndarray, family: str, names=None) -> Clip:
    t = frames.shape[0]
    names = names or [f"{i:05d}" for i in range(t)]
    return Clip(frames=frames.astype(np.float32), source=f"synthetic:{family}", names=names,
                fps=24.0, bit_depth=8, exif_exposures=None, meta={"kind": "synthetic"})
