"""Scores of whole clips against their ground truth: frames aligned by the best sub-pixel shift
(``best_shift``), one global scale per clip (``global_scale``), the DeepHDRVideo protocol
(``deephdr_metrics``), and metrics accumulated frame by frame (``hdr_metrics_streamed``)."""

from __future__ import annotations

import numpy as np

from layercam.core.metrics import (MetricInputError, PSNR_CAP, _REL_FLOOR, _finite_gt, _pair,
                                   _psnr_masked, _ssim_arrays, ldr_metrics, mu_law)


# -- sharp frames against ground truth (deblurring) ------------------------------------------------
def _translate(img: np.ndarray, dx: float, dy: float) -> np.ndarray:
    import cv2

    m = np.array([[1, 0, dx], [0, 1, dy]], np.float64)
    return cv2.warpAffine(img, m, img.shape[1::-1], flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101)


def best_shift(pred: np.ndarray, gt: np.ndarray, crop: int,
               max_shift: float = 3.0) -> tuple[np.ndarray, tuple[float, float]]:
    """Translate ``pred (H, W, 3)`` by the shift (within ``max_shift`` px, 0.25 px steps) that
    minimises its squared error to ``gt`` inside a ``crop``-pixel border: a deblurred frame may show
    any instant of the exposure, and the blurry frame its blur's centre, so both are compared at
    their best shift."""
    c = (slice(crop, pred.shape[0] - crop), slice(crop, pred.shape[1] - crop))

    def err(dx, dy):
        return float(((_translate(pred, dx, dy)[c] - gt[c]) ** 2).mean())

    n = int(max_shift)
    best = min(((dx, dy) for dx in range(-n, n + 1) for dy in range(-n, n + 1)), key=lambda d: err(*d))
    fine = [(best[0] + a / 4, best[1] + b / 4) for a in range(-3, 4) for b in range(-3, 4)]
    fine = [d for d in fine if abs(d[0]) <= max_shift and abs(d[1]) <= max_shift]
    dx, dy = min(fine, key=lambda d: err(*d))
    return _translate(pred, dx, dy), (float(dx), float(dy))


def score_frames(pred: np.ndarray, gt: np.ndarray, crop: int, align: bool) -> list[dict]:
    """Per frame ``{"psnr", "ssim"}`` of LDR ``pred`` against ``gt`` (both ``(T, H, W, 3)``), with a
    ``crop``-pixel border left out; ``align`` first moves each frame by its :func:`best_shift`."""
    rows = []
    for p, g in zip(pred, gt):
        shift = (0.0, 0.0)
        if align:
            p, shift = best_shift(p, g, max(crop, 4))
        c = (slice(crop, p.shape[0] - crop), slice(crop, p.shape[1] - crop)) if crop else (slice(None), slice(None))
        m = ldr_metrics(np.clip(p[c], 0, 1), g[c])
        rows.append({"psnr": round(m["psnr"], 3), "ssim": round(m["ssim"], 4),
                     "shift": [round(shift[0], 2), round(shift[1], 2)]})
    return rows


def global_scale(pred, gt) -> float:
    """One scale for all channels that puts a relative HDR prediction on the ground truth's
    radiometric scale: ``exp(median(log gt - log pred))`` over every pixel and channel where both
    are above ``1e-6`` of their maximum and gt is finite (1 when none qualifies)."""
    p, g = _pair(pred, gt)
    ok = np.broadcast_to(_finite_gt(g), g.shape)
    gz = np.where(ok, g, 0.0)
    m = ok & (p > _REL_FLOOR * max(float(np.abs(p).max()), 1e-30)) & (gz > _REL_FLOOR * max(float(gz.max()), 1e-30))
    return float(np.exp(np.median(np.log(gz[m]) - np.log(p[m])))) if m.any() else 1.0


def deephdr_metrics(pred, gt, mu: float = 5000.0) -> dict[str, float]:
    """``{"psnr_t", "psnr_l", "ssim_t"}`` as the DeepHDRVideo evaluation computes them (Chen et al.,
    ICCV 2021; the Kalantari and Ramamoorthi 2017 convention), so that numbers compare with
    published HDR-video tables.

    What we followed, from guanyingc/DeepHDRVideo (commit 1642bbd): ``datasets/real_benchmark_dataset.py``
    divides each ground-truth HDR by its maximum when that maximum is above 1 (one scalar for all
    channels; a ground truth already in [0, 1] is left as it is); ``matlab/paral_eval_HDRs.m``
    scores each frame on its own, ``PSNR-L = psnr(est, gt)`` and ``PSNR-T = psnr(mulog(est),
    mulog(gt))`` with ``matlab/mulog_tonemap.m`` (``log(1 + mu x) / log(1 + mu)``, mu = 5000) and
    MATLAB's ``psnr`` (peak 1), then averages the per-frame values; SSIM-T (``utils/eval_utils.py``,
    ``ssim_matlab``: Gaussian window 11, sigma 1.5, range 1) is the SSIM of the mu-law images.
    The networks there output HDR already on the ground truth's scale and in [0, 1] (a sigmoid), so
    the protocol does no alignment. layercam and OpenCV give HDR on a scale of their own, so the
    prediction is first put on the ground truth's scale by ONE scalar for all channels
    (:func:`global_scale`: colour casts count, unlike :func:`psnr_mu`'s per-channel alignment),
    then divided by the same number as the ground truth and clipped to [0, 1] (the range a sigmoid
    output has).

    pred, gt: ``(H,W,C)`` or ``(T,H,W,C)`` linear HDR. Returns per-frame means.
    """
    p, g = _pair(pred, gt)
    if p.ndim == 3:
        p, g = p[None], g[None]
    rows = []
    for pf, gf in zip(p, g):
        ok = _finite_gt(gf)
        gf = np.where(ok, gf, 0.0)
        norm = max(float(gf.max()), 1.0)
        pn = np.clip(pf * global_scale(pf, gf) / norm, 0.0, 1.0)
        gn = gf / norm
        tp, tg = mu_law(pn, mu), mu_law(gn, mu)
        rows.append((_psnr_masked(tp, tg, ok, 1.0), _psnr_masked(pn, gn, ok, 1.0), _ssim_arrays(tp, tg)))
    psnr_t, psnr_lin, ssim_t = (float(np.mean(c)) for c in zip(*rows))
    return {"psnr_t": psnr_t, "psnr_l": psnr_lin, "ssim_t": ssim_t}


def hdr_metrics_streamed(pred_frame, gt_frame, n: int, mu: float = 5000.0) -> dict[str, float]:
    """:func:`hdr_metrics` of a clip read one frame at a time, for clips too large to hold
    (1080p): ``pred_frame(t)`` and ``gt_frame(t)`` return frame ``t`` ``(H,W,C)``. Three passes
    (maxima; log ratios for the per-channel median scale, kept in float32; errors and SSIM per
    frame): the same numbers as ``hdr_metrics`` on the stacked clip to within float32 rounding of
    the log ratios."""
    if n < 1:
        raise MetricInputError("no frames")

    def pair(t):
        p, g = _pair(pred_frame(t), gt_frame(t))
        ok = np.all(np.isfinite(g), axis=-1, keepdims=True)
        return p, np.where(ok, g, 0.0), ok

    c = None
    for t in range(n):  # pass 0: maxima (align_scale's floors, the normalisation)
        p, gz, ok = pair(t)
        if c is None:
            c, pmax, gmax_c, any_ok = p.shape[-1], np.zeros(p.shape[-1]), np.zeros(p.shape[-1]), False
        pmax = np.maximum(pmax, np.abs(p).reshape(-1, c).max(0))
        gmax_c = np.maximum(gmax_c, np.abs(gz).reshape(-1, c).max(0))
        any_ok |= bool(ok.any())
    if not any_ok:
        raise MetricInputError("ground truth has no finite pixel")
    fp, fg = _REL_FLOOR * np.maximum(pmax, 1e-30), _REL_FLOOR * np.maximum(gmax_c, 1e-30)
    ratios = [[] for _ in range(c)]
    sums = np.zeros((c, 2))
    for t in range(n):  # pass 1: the per-channel scale, as align_scale
        p, gz, ok = pair(t)
        for k in range(c):
            pc, gc, oc = p[..., k], gz[..., k], ok[..., 0]
            m = oc & (pc > fp[k]) & (gc > fg[k])
            ratios[k].append((np.log(gc[m]) - np.log(pc[m])).astype(np.float32))
            sums[k] += (gc[oc].sum(), pc[oc].sum())
    scale = np.ones(c)
    for k in range(c):
        r = np.concatenate(ratios[k])
        if r.size:
            scale[k] = float(np.exp(np.median(r.astype(np.float64))))
        elif sums[k, 1] > 0:
            scale[k] = sums[k, 0] / sums[k, 1]
    ratios = None
    gmax = float(gmax_c.max())
    if not gmax > 0:
        raise MetricInputError("ground-truth HDR has no positive value")
    se_mu = se_l = 0.0
    count = 0
    ssims = []
    for t in range(n):  # pass 2: errors and SSIM, as psnr_mu / psnr_l / ssim_mu
        p, gz, ok = pair(t)
        pn = np.clip((p * scale).astype(np.float32).astype(np.float64) / gmax, 0.0, 1.0)
        gn = np.clip(gz / gmax, 0.0, None)
        okb = np.broadcast_to(ok, gn.shape)
        pm, gm = mu_law(pn, mu), mu_law(gn, mu)
        se_mu += float(((pm - gm) ** 2)[okb].sum())
        se_l += float(((pn - gn) ** 2)[okb].sum())
        count += int(okb.sum())
        ssims.append(_ssim_arrays(pm, gm))

    def to_db(se):
        mse = se / max(count, 1)
        return PSNR_CAP if mse <= 10.0 ** (-PSNR_CAP / 10.0) else float(10.0 * np.log10(1.0 / mse))

    return {"psnr_mu": to_db(se_mu), "psnr_l": to_db(se_l), "ssim_mu": float(np.mean(ssims))}
