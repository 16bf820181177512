"""Scores of the real suite beyond ``layercam.metrics``: which pixels no exposure saw, which pixels
of a real video stay still, and how much a tonemapped video flickers there.

Encoded images are float in [0,1] ``(..., H, W, 3)``.
"""

from __future__ import annotations

import numpy as np

from layercam import metrics

__all__ = ["UNDER", "OVER", "unseen_mask", "static_mask", "flicker", "scored_channels", "score_hdr", "display_hdr", "error_map"]

OVER = 245.0 / 255.0  # at or above: clipped (NTIRE's LDRs saturate at code 248, not 255)
UNDER = 2.0 / 255.0  # at or below in every channel: lost in the noise floor


def unseen_mask(stack: np.ndarray) -> np.ndarray:
    """Pixels that no image of ``stack`` ``(N,...,H,W,3)`` (one view, N exposures) saw: in every
    image some channel is clipped (``>= OVER``) or every channel is in the noise floor
    (``<= UNDER``). Returns a bool array of the stack's shape without N and the channels."""
    s = np.asarray(stack)
    seen = (s.max(axis=-1) < OVER) & (s.max(axis=-1) > UNDER)
    return ~seen.any(axis=0)


def static_mask(frames: np.ndarray, period: int = 2, thr: float = 8.0 / 255.0, margin: int = 4) -> np.ndarray:
    """Pixels of a fixed-camera clip ``(T,H,W,3)`` that stay still through it.

    Frames ``period`` apart share an exposure (2 for alternating exposures), so they can be compared
    directly: a pixel is static if, after a 3x3 box blur, every such pair differs by less than
    ``thr`` in every channel, it lies more than ``margin`` px from any pixel that is not, and the
    clip's exposures see it (not :func:`unseen_mask` in some pair of neighbouring frames).
    Returns ``(H,W)`` bool."""
    import cv2

    f = np.stack([cv2.blur(x, (3, 3)) for x in np.asarray(frames, np.float32)])
    diff = np.abs(f[period:] - f[:-period]).max(axis=-1).max(axis=0)
    moving = (diff >= thr).astype(np.uint8)
    if margin > 0:
        moving = cv2.dilate(moving, np.ones((2 * margin + 1, 2 * margin + 1), np.uint8))
    unseen = np.zeros(moving.shape, bool)
    for t in range(len(frames) - 1):
        unseen |= unseen_mask(np.asarray(frames[t : t + 2]))
    return (moving == 0) & ~unseen


def flicker(display: np.ndarray, mask: np.ndarray) -> float:
    """Mean absolute frame-to-frame change of a display video ``(T,H,W,3)`` in [0,1] over the
    pixels of ``mask`` ``(H,W)``, in 8-bit code values (mean over channels, pixels and the T-1
    pairs). NaN when the mask is empty."""
    if not mask.any() or len(display) < 2:
        return float("nan")
    d = np.abs(np.diff(np.asarray(display, np.float32), axis=0))[:, mask]
    return float(d.mean() * 255.0)


def scored_channels(gt: np.ndarray) -> list[int]:
    """The channels of a ground truth ``(..., 3)`` that carry a signal: positive in at least half
    of the pixels. The NTIRE crops' green channel is 0 in 80-100% of pixels (a magenta-lit stage
    under the 16-bit source's floor, radiance < 0.006 against maxima of 0.2-23): a per-channel
    scale cannot be fitted to it, and the mu-law's resolution there is finer than the truth's own
    (its floor alone is 0.1 in mu-law units), so such a channel is left out of every score."""
    g = np.asarray(gt)
    return [c for c in range(g.shape[-1]) if (g[..., c] > 0).mean() >= 0.5]


def score_hdr(pred: np.ndarray, gt: np.ndarray, unseen: np.ndarray, fg: np.ndarray | None = None) -> dict:
    """Every score of a linear HDR prediction against ground truth (or a reference), ``(H,W,3)`` or
    ``(T,H,W,3)`` each, on :func:`scored_channels`: ``psnr_mu``, ``psnr_l``, ``ssim_mu``
    (``layercam.metrics``: one scale per channel), ``psnr_mu_recov`` (the same on the pixels some
    exposure saw, i.e. not ``unseen``), ``psnr_mu_fg`` (on the foreground mask ``fg`` when given),
    the DeepHDRVideo protocol's ``psnr_t``, ``psnr_l_t``, ``ssim_t``
    (:func:`layercam.metrics.deephdr_metrics`) and ``channels`` (e.g. "RGB", "RB")."""
    keep = scored_channels(gt)
    pred, gt = np.asarray(pred)[..., keep], np.asarray(gt)[..., keep]
    m = metrics.hdr_metrics(pred, gt)
    out = {k: m[k] for k in ("psnr_mu", "psnr_l", "ssim_mu")}
    seen = ~np.asarray(unseen, bool)
    out["psnr_mu_recov"] = metrics.highlight_psnr_mu(pred, gt, seen) if seen.any() else float("nan")
    if fg is not None:
        out["psnr_mu_fg"] = metrics.highlight_psnr_mu(pred, gt, fg) if fg.any() else float("nan")
    d = metrics.deephdr_metrics(pred, gt)
    out.update(psnr_t=d["psnr_t"], psnr_l_t=d["psnr_l"], ssim_t=d["ssim_t"], channels="".join("RGB"[c] for c in keep))
    return out


def display_hdr(pred: np.ndarray, gt: np.ndarray | None = None) -> np.ndarray:
    """What the scores see, for figures: the prediction aligned per channel to ``gt``, both divided
    by gt's maximum, mu-law (mu = 5000); channels left out of the scores (:func:`scored_channels`)
    are shown black. Without gt: ``layercam.render.tonemap_display``."""
    if gt is None:
        from layercam.render import tonemap_display

        return tonemap_display(np.asarray(pred, np.float32))[0]
    p = metrics.align_scale(pred, gt)
    p[..., [c for c in range(p.shape[-1]) if c not in scored_channels(gt)]] = 0.0
    gmax = float(np.nanmax(gt))
    return metrics.mu_law(np.clip(p / gmax, 0, 1)).astype(np.float32)


def error_map(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """``|mu(pred) - mu(gt)|`` per pixel (mean over the scored channels) after :func:`display_hdr`'s
    normalisation. ``(..., H, W)``."""
    keep = scored_channels(gt)
    return np.abs(display_hdr(pred, gt) - display_hdr(gt, gt))[..., keep].mean(axis=-1)
