"""Image metrics: numpy arrays in, Python floats out.

Images are ``(H,W,C)`` or ``(T,H,W,C)`` (C = 3 usually). HDR metrics follow the paper
(CVPR 2023, Sec. 4): HDR images are tone-mapped with the mu-law (mu = 5000) and compared with
PSNR / SSIM ("PSNR-mu", "SSIM-mu"), or compared linearly ("PSNR-L").

HDR from a relative model is aligned to the ground truth by one scale per channel, the median
ratio (``align_scale``); then both are normalised by the ground truth's maximum, the
prediction is clipped to [0,1], and the mu-law is applied.

Guards: a NaN/inf in a prediction raises ``MetricInputError`` (a ``ValueError`` and a
``LayercamError``); non-finite ground-truth pixels are left out; identical images give a
finite PSNR capped at ``PSNR_CAP`` dB.
"""

from __future__ import annotations

import numpy as np

from layercam.core.errors import LayercamError

__all__ = [
    "MetricInputError",
    "PSNR_CAP",
    "align_scale",
    "hdr_metrics",
    "highlight_psnr_mu",
    "iou",
    "ldr_metrics",
    "mu_law",
    "psnr",
    "psnr_l",
    "psnr_mu",
    "ssim",
    "ssim_mu",
]

PSNR_CAP = 100.0  # dB, returned for (numerically) identical images
_REL_FLOOR = 1e-6  # pixels below this fraction of the max are ignored by align_scale


class MetricInputError(LayercamError, ValueError):
    """Bad metric input: mismatched shapes, wrong rank, NaN/inf in a prediction."""


# --------------------------------------------------------------------------------------------
# Entry checks
# --------------------------------------------------------------------------------------------


def _pair(pred, gt) -> tuple[np.ndarray, np.ndarray]:
    """Validate and convert a (pred, gt) pair to float64 arrays of the same (H,W,C)/(T,H,W,C)."""
    p = np.asarray(pred, dtype=np.float64)
    g = np.asarray(gt, dtype=np.float64)
    if p.shape != g.shape:
        raise MetricInputError(f"shape mismatch: pred {p.shape} vs gt {g.shape}")
    if p.ndim not in (3, 4):
        raise MetricInputError(f"expected (H,W,C) or (T,H,W,C), got shape {p.shape}")
    if p.size == 0:
        raise MetricInputError("empty images")
    if not np.all(np.isfinite(p)):
        raise MetricInputError("prediction contains NaN or inf")
    return p, g


def _finite_gt(g: np.ndarray) -> np.ndarray:
    """Mask of finite ground-truth pixels (all channels finite), broadcastable to g."""
    ok = np.all(np.isfinite(g), axis=-1, keepdims=True)
    if not ok.any():
        raise MetricInputError("ground truth has no finite pixel")
    return ok


# --------------------------------------------------------------------------------------------
# Scale alignment and tone mapping
# --------------------------------------------------------------------------------------------


def align_scale(pred, gt, valid=None) -> np.ndarray:
    """Align a relative HDR prediction to the ground truth by one scale per channel.

    HDR from a relative model is aligned to the ground truth by one scale per channel, the
    median ratio: ``s_c = exp(median(log gt_c - log pred_c))`` over pixels where both are
    above a small floor (``1e-6`` times their maximum), the ground truth is finite, and
    ``valid`` (optional bool mask ``(H,W)``/``(T,H,W)`` or the full shape) is True. A channel
    without such pixels falls back to the ratio of sums (or 1).

    pred, gt: ``(H,W,C)`` or ``(T,H,W,C)``. Returns ``pred * s`` (float32, same shape).
    """
    p, g = _pair(pred, gt)
    ok = np.broadcast_to(_finite_gt(g), g.shape)
    if valid is not None:
        v = np.asarray(valid, dtype=bool)
        if v.shape == g.shape[:-1]:
            v = v[..., None]
        try:
            ok = ok & np.broadcast_to(v, g.shape)
        except ValueError:
            raise MetricInputError(f"valid mask shape {v.shape} does not fit {g.shape}") from None
    gz = np.where(ok, g, 0.0)
    out = np.empty_like(p)
    for c in range(p.shape[-1]):
        pc, gc, oc = p[..., c], gz[..., c], ok[..., c]
        fp = _REL_FLOOR * max(float(np.max(np.abs(pc))), 1e-30)
        fg = _REL_FLOOR * max(float(np.max(np.abs(gc))), 1e-30)
        m = oc & (pc > fp) & (gc > fg)
        if m.any():
            s = float(np.exp(np.median(np.log(gc[m]) - np.log(pc[m]))))
        else:
            sp = float(pc[oc].sum())
            s = float(gc[oc].sum()) / sp if sp > 0 else 1.0
        out[..., c] = pc * s
    return out.astype(np.float32)


def mu_law(x, mu: float = 5000.0) -> np.ndarray:
    """``log(1 + mu x) / log(1 + mu)``; x in [0,1] (negatives are clipped to 0)."""
    x = np.maximum(np.asarray(x, dtype=np.float64), 0.0)
    return np.log1p(mu * x) / np.log1p(mu)


def _normalise_hdr(pred_hdr, gt_hdr, align: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Align (optional), divide both by the finite gt max, clip pred to [0,1].

    Returns (pred_n, gt_n, finite-gt mask) as float64; non-finite gt pixels are set to 0.
    """
    p, g = _pair(pred_hdr, gt_hdr)
    ok = _finite_gt(g)
    if align:
        p = align_scale(p, g).astype(np.float64)
    g = np.where(ok, g, 0.0)
    gmax = float(np.max(g))
    if not gmax > 0:
        raise MetricInputError("ground-truth HDR has no positive value")
    return np.clip(p / gmax, 0.0, 1.0), np.clip(g / gmax, 0.0, None), ok


# --------------------------------------------------------------------------------------------
# PSNR
# --------------------------------------------------------------------------------------------


def _psnr_masked(p: np.ndarray, g: np.ndarray, ok: np.ndarray | None, peak: float) -> float:
    d2 = (p - g) ** 2
    if ok is not None:
        okb = np.broadcast_to(ok, d2.shape)
        mse = float(d2[okb].mean())
    else:
        mse = float(d2.mean())
    if mse <= peak**2 * 10.0 ** (-PSNR_CAP / 10.0):
        return PSNR_CAP
    return float(10.0 * np.log10(peak**2 / mse))


def psnr(pred, gt, peak: float = 1.0) -> float:
    """PSNR in dB over all pixels (and frames) where gt is finite; capped at ``PSNR_CAP``."""
    p, g = _pair(pred, gt)
    ok = _finite_gt(g)
    return _psnr_masked(p, np.where(ok, g, 0.0), ok, float(peak))


def psnr_mu(pred_hdr, gt_hdr, mu: float = 5000.0, align: bool = True) -> float:
    """PSNR-mu: align (per-channel median ratio), normalise both by the gt max, clip pred to
    [0,1], mu-law tone-map both, PSNR with peak 1."""
    p, g, ok = _normalise_hdr(pred_hdr, gt_hdr, align)
    return _psnr_masked(mu_law(p, mu), mu_law(g, mu), ok, 1.0)


def psnr_l(pred_hdr, gt_hdr, align: bool = True) -> float:
    """PSNR-L: the same normalisation as ``psnr_mu`` then linear PSNR with peak 1."""
    p, g, ok = _normalise_hdr(pred_hdr, gt_hdr, align)
    return _psnr_masked(p, g, ok, 1.0)


# --------------------------------------------------------------------------------------------
# SSIM
# --------------------------------------------------------------------------------------------


def _ssim_arrays(p: np.ndarray, g: np.ndarray, window: int = 11) -> float:
    import torch
    import kornia

    if p.ndim == 3:
        p, g = p[None], g[None]
    tp = torch.from_numpy(np.ascontiguousarray(p, dtype=np.float32)).permute(0, 3, 1, 2)
    tg = torch.from_numpy(np.ascontiguousarray(g, dtype=np.float32)).permute(0, 3, 1, 2)
    with torch.no_grad():
        m = kornia.metrics.ssim(tp, tg, window_size=window, max_val=1.0)
    return float(m.mean(dim=(1, 2, 3)).mean())


def ssim(pred, gt, window: int = 11) -> float:
    """Mean SSIM (kornia, Gaussian window 11, max_val 1) of [0,1] images, averaged over frames.
    Non-finite gt pixels are replaced by 0 (they have no meaningful neighbourhood)."""
    p, g = _pair(pred, gt)
    g = np.where(_finite_gt(g), g, 0.0)
    return _ssim_arrays(p, g, window)


def ssim_mu(pred_hdr, gt_hdr, mu: float = 5000.0, align: bool = True, window: int = 11) -> float:
    """SSIM-mu: SSIM of the mu-law images after the ``psnr_mu`` normalisation."""
    p, g, _ = _normalise_hdr(pred_hdr, gt_hdr, align)
    return _ssim_arrays(mu_law(p, mu), mu_law(g, mu), window)


# --------------------------------------------------------------------------------------------
# Bundles and masks
# --------------------------------------------------------------------------------------------


def hdr_metrics(pred, gt, mu: float = 5000.0, align: bool = True) -> dict[str, float]:
    """``{"psnr_mu", "psnr_l", "ssim_mu"}`` of a linear HDR prediction against linear gt."""
    return {
        "psnr_mu": psnr_mu(pred, gt, mu, align),
        "psnr_l": psnr_l(pred, gt, align),
        "ssim_mu": ssim_mu(pred, gt, mu, align),
    }


def ldr_metrics(pred, gt) -> dict[str, float]:
    """``{"psnr", "ssim"}`` of [0,1] LDR images."""
    return {"psnr": psnr(pred, gt), "ssim": ssim(pred, gt)}


def iou(mask_pred, mask_gt) -> float:
    """Intersection over union of two boolean masks of equal shape; 1.0 when both are empty."""
    a = np.asarray(mask_pred).astype(bool)
    b = np.asarray(mask_gt).astype(bool)
    if a.shape != b.shape:
        raise MetricInputError(f"shape mismatch: {a.shape} vs {b.shape}")
    union = int(np.logical_or(a, b).sum())
    if union == 0:
        return 1.0
    return float(np.logical_and(a, b).sum() / union)


def highlight_psnr_mu(pred_hdr, gt_hdr, mask, mu: float = 5000.0, align: bool = True) -> float:
    """PSNR-mu restricted to the pixels of ``mask`` (bool ``(H,W)`` / ``(T,H,W)`` or the full shape),
    e.g. the highlights clipped in some exposure. Alignment and normalisation are those of
    :func:`psnr_mu` over the whole image; only the error is averaged over the mask."""
    p, g, ok = _normalise_hdr(pred_hdr, gt_hdr, align)
    m = np.asarray(mask, dtype=bool)
    if m.shape == g.shape[:-1]:
        m = m[..., None]
    try:
        sel = np.broadcast_to(m, g.shape) & np.broadcast_to(ok, g.shape)
    except ValueError:
        raise MetricInputError(f"mask shape {m.shape} does not fit {g.shape}") from None
    if not sel.any():
        raise MetricInputError("highlight mask selects no pixel")
    return _psnr_masked(mu_law(p, mu), mu_law(g, mu), sel, 1.0)


# --------------------------------------------------------------------------------------------
# The DeepHDRVideo protocol (published HDR-video tables)
# --------------------------------------------------------------------------------------------


