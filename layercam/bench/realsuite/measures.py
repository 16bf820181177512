"""Scores of the real suite beyond ``layercam.core.metrics``: which pixels no exposure saw, which pixels
of a real video hold still (after registering the camera's motion), how much a tonemapped
video flickers there, and deblurred frames against sharp ones.

Encoded images are float in [0,1] ``(..., H, W, 3)``.
"""

from __future__ import annotations

import numpy as np

from layercam.core import frame_metrics, metrics

__all__ = ["UNDER", "OVER", "unseen_mask", "registration", "warp_into", "static_masks", "flicker",
           "scored_channels", "score_hdr", "score_deblur", "display_hdr", "error_map"]

OVER = 245.0 / 255.0  # at or above: clipped (NTIRE's LDRs saturate at code 248, not 255)
UNDER = 2.0 / 255.0  # at or below in every channel: lost in the noise floor


def unseen_mask(stack: np.ndarray) -> np.ndarray:
    """Pixels that no image of ``stack`` ``(N,...,H,W,3)`` (one view, N exposures) saw: in every
    image some channel is clipped (``>= OVER``) or every channel is in the noise floor
    (``<= UNDER``). Returns a bool array of the stack's shape without N and the channels."""
    s = np.asarray(stack)
    seen = (s.max(axis=-1) < OVER) & (s.max(axis=-1) > UNDER)
    return ~seen.any(axis=0)


def registration(frames: np.ndarray) -> np.ndarray:
    """Homographies ``(T-1,3,3)`` from frame t to frame t+1 (pixel coordinates) of a clip
    ``(T,H,W,3)``: layercam's exposure-invariant DIS flow (``dis_medium``) and its RANSAC fit
    (``layercam.vision.flow.global_homographies``)."""
    from layercam.vision import flow

    fw, _ = flow.compute_flow(frames, method="dis_medium", progress=False)
    return flow.global_homographies(fw)


def warp_into(img: np.ndarray, hom: np.ndarray, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
    """Frame ``b``'s image ``img`` ``(H,W,C)`` resampled into frame ``a``'s view (a < b) through
    the chained homographies ``hom`` (t -> t+1); returns it and the ``(H,W)`` mask of pixels
    that fall inside frame ``b``."""
    import cv2

    m = np.eye(3)
    for t in range(a, b):
        m = hom[t] @ m
    h, w = img.shape[:2]
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    out = cv2.warpPerspective(np.ascontiguousarray(img, np.float32), m, (w, h), flags=flags,
                              borderMode=cv2.BORDER_REPLICATE)
    inside = cv2.warpPerspective(np.ones((h, w), np.float32), m, (w, h), flags=flags,
                                 borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out.reshape(img.shape), inside > 0.999


def static_masks(frames: np.ndarray, hom: np.ndarray, period: int = 2, thr: float = 8.0 / 255.0,
                 margin: int = 4) -> np.ndarray:
    """For each pair (t, t+1), t < T - period, the pixels of frame t's view that hold still:
    ``(T-period,H,W)`` bool.

    The camera may move, so frames are compared after registration (:func:`warp_into` with
    :func:`registration`'s homographies). Frames ``period`` apart share an exposure (2 for
    alternating exposures), so they can be compared directly: a pixel is static if, after a 3x3
    box blur, frame t and frame t+period warped into t's view differ by less than ``thr`` in every
    channel, it lies more than ``margin`` px from any pixel that does not, frames t+1 and t+period
    both cover it, and frames t and t+1 are not both clipped there (:func:`unseen_mask`)."""
    import cv2

    f = np.stack([cv2.blur(x, (3, 3)) for x in np.asarray(frames, np.float32)])
    kernel = np.ones((2 * margin + 1, 2 * margin + 1), np.uint8)
    out = []
    for t in range(len(f) - period):
        far, in_far = warp_into(f[t + period], hom, t, t + period)
        nxt, in_nxt = warp_into(np.asarray(frames[t + 1], np.float32), hom, t, t + 1)
        moving = (np.abs(f[t] - far).max(axis=-1) >= thr).astype(np.uint8)
        if margin > 0:
            moving = cv2.dilate(moving, kernel)
        out.append((moving == 0) & in_far & in_nxt & ~unseen_mask(np.stack([frames[t], nxt])))
    return np.stack(out)


def flicker(display: np.ndarray, hom: np.ndarray, static: np.ndarray) -> float:
    """Frame-to-frame change of a display video ``(T,H,W,3)`` in [0,1] on static pixels, in 8-bit
    code values: for each pair (t, t+1) with a mask in ``static`` (:func:`static_masks`), the
    mean of ``|D_t - D_(t+1) warped into t's view|`` over the mask and the channels; then the mean
    over pairs (weighted by their pixel counts). NaN when no pixel is static."""
    total, count = 0.0, 0
    for t, m in enumerate(static):
        if not m.any():
            continue
        nxt, _ = warp_into(display[t + 1], hom, t, t + 1)
        total += float(np.abs(display[t] - nxt)[m].sum())
        count += int(m.sum()) * display.shape[-1]
    return total / count * 255.0 if count else float("nan")


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
    (``layercam.core.metrics``: one scale per channel), ``psnr_mu_recov`` (the same on the pixels some
    exposure saw, i.e. not ``unseen``), ``psnr_mu_fg`` (on the foreground mask ``fg`` when given),
    the DeepHDRVideo protocol's ``psnr_t``, ``psnr_l_t``, ``ssim_t``
    (:func:`layercam.core.frame_metrics.deephdr_metrics`) and ``channels`` (e.g. "RGB", "RB")."""
    keep = scored_channels(gt)
    pred, gt = np.asarray(pred)[..., keep], np.asarray(gt)[..., keep]
    m = metrics.hdr_metrics(pred, gt)
    out = {k: m[k] for k in ("psnr_mu", "psnr_l", "ssim_mu")}
    seen = ~np.asarray(unseen, bool)
    out["psnr_mu_recov"] = metrics.highlight_psnr_mu(pred, gt, seen) if seen.any() else float("nan")
    if fg is not None:
        out["psnr_mu_fg"] = metrics.highlight_psnr_mu(pred, gt, fg) if fg.any() else float("nan")
    d = frame_metrics.deephdr_metrics(pred, gt)
    out.update(psnr_t=d["psnr_t"], psnr_l_t=d["psnr_l"], ssim_t=d["ssim_t"], channels="".join("RGB"[c] for c in keep))
    return out


def display_hdr(pred: np.ndarray, gt: np.ndarray | None = None) -> np.ndarray:
    """For figures: the prediction aligned per channel to ``gt`` (channels left out of the scores,
    :func:`scored_channels`, black), then ``layercam.scene.render.tonemap_display`` (the preview's global
    Reinhard + sRGB) with the statistics of ``gt``, so that every panel of a case is shown alike.
    Without gt: the prediction's own tonemap."""
    from layercam.scene.render import tonemap_display

    if gt is None:
        return tonemap_display(np.asarray(pred, np.float32))[0]
    g = np.asarray(gt, np.float32).copy()
    p = metrics.align_scale(pred, g)
    off = [c for c in range(p.shape[-1]) if c not in scored_channels(g)]
    p[..., off], g[..., off] = 0.0, 0.0
    return tonemap_display(p, tonemap_display(g)[1])[0]


def _mu_normalised(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """The prediction as the scores see it: aligned per channel, divided by gt's maximum, mu-law."""
    return metrics.mu_law(np.clip(metrics.align_scale(pred, gt) / float(np.nanmax(gt)), 0, 1))


def error_map(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """``|mu(pred) - mu(gt)|`` per pixel, mean over the scored channels, in the scores' units (aligned
    per channel, both divided by gt's maximum, mu-law). ``(..., H, W)``."""
    keep = scored_channels(gt)
    return np.abs(_mu_normalised(pred, gt) - _mu_normalised(gt, gt))[..., keep].mean(axis=-1).astype(np.float32)


ALIGN_CROP = 8  # px: the border the aligned score leaves out (what a shift of up to 3 px moves in)


def score_deblur(pred: np.ndarray, sharp: np.ndarray, floor: np.ndarray | None = None) -> dict:
    """Sharp frames ``pred (T,H,W,3)`` in [0,1] against the truth ``sharp`` (same shape), as a user
    sees them (sRGB, whole frame, no shift): ``psnr``/``ssim`` (means over the frames), ``psnr_frames``
    (per frame) and, against ``floor`` (the blurry input's per-frame PSNR, ``(T,)``), ``gain_db``
    (mean PSNR over the floor's mean), ``worst_gain_db`` (the frame that gains least) and
    ``frames_below`` (frames scoring under their input). ``psnr_aligned``: the mean PSNR with each
    frame first moved by its best shift within 3 px (:func:`layercam.core.frame_metrics.score_frames`,
    a ``ALIGN_CROP`` border left out): a sharp frame may show any instant of the exposure (the truth
    shows its middle, a deblurred frame naturally its blur's centre of mass), so this scores the
    sharpness apart from that instant."""
    pred, sharp = np.clip(np.asarray(pred, np.float32), 0, 1), np.asarray(sharp, np.float32)
    rows = [metrics.ldr_metrics(p, g) for p, g in zip(pred, sharp)]
    ps = np.round([r["psnr"] for r in rows], 3)  # as listed (the floor: another method's psnr_frames)
    aligned = frame_metrics.score_frames(pred, sharp, ALIGN_CROP, align=True)
    out = {"psnr": float(ps.mean()), "ssim": float(np.mean([r["ssim"] for r in rows])),
           "psnr_frames": [float(v) for v in ps],
           "psnr_aligned": float(np.mean([r["psnr"] for r in aligned]))}
    if floor is not None:
        gain = ps - np.asarray(floor, np.float64)
        out.update(gain_db=float(ps.mean() - np.mean(floor)), worst_gain_db=float(gain.min()),
                   frames_below=int((gain < 0).sum()))
    return out
