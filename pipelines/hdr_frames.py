"""The clip's HDR frames as the export renders them: a first pass at a small size for the preview's
clip-wide statistics and the peak (:func:`first_pass`), then each frame once, corrected towards the
frame where it saw well (:func:`faithful_hdr`, :mod:`layercam.camera.faithful`), and what the
corrections did (:func:`faithful_summary`)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from layercam.core.errors import LayercamError
from layercam.core.interrupts import reached
from layercam.pipelines.runner import Context
from layercam.vision.scale import size_within

# The preview's clip-wide tonemap statistics and the EXRs' type come from a first pass over every
# frame rendered at most this many pixels (every pixel of a clip up to 256x256; 1/32 of a 1080p
# frame): the export then renders each frame once, writes it and lets it go, so that its memory
# does not grow with the clip.
FIRST_PASS_PIXELS = 65536
FIRST_PASS_TOTAL = 64 * FIRST_PASS_PIXELS  # ... and at most this many over the clip (a longer clip: fewer a frame)


def first_pass(ctx: Context, model) -> tuple[dict, float]:
    """Every frame rendered at most :data:`FIRST_PASS_PIXELS` pixels -> the preview's display
    statistics (:func:`layercam.scene.render.display_stats`) and the clip's peak irradiance. Refuses (one
    line) non-finite irradiance before anything is written."""
    from layercam.scene import render
    from layercam.core.colour import REC709, luma

    hw = size_within((ctx.clip.H, ctx.clip.W), min(FIRST_PASS_PIXELS, FIRST_PASS_TOTAL // ctx.clip.T))
    lum, peak = [], 0.0
    for t in ctx.frames_bar("export (first pass)"):
        hdr = render.render_frame(model, t, hw, ("hdr",))["hdr"]
        if not np.isfinite(hdr).all():
            raise LayercamError(f"frame_{t:05d}.exr: the model rendered non-finite irradiance; not writing it")
        lum.append(luma(hdr, REC709).ravel())
        peak = max(peak, float(hdr.max()))
    return render.display_stats(np.concatenate(lum)), peak


def faithful_hdr(ctx: Context, model, ts, geometry=None) -> Iterator[tuple[int, np.ndarray, dict]]:
    """For each frame ``t`` of ``ts`` in turn: ``(t, linear HDR (H, W, 3), what the correction did)``.
    With ``export.faithful`` the model corrected towards the frame where it saw well, and where it
    did not towards its neighbours' corrections moved along the clip's flow
    (:mod:`layercam.camera.faithful`); else the model alone (and ``{}``). Each frame's correction is
    computed once and kept while a neighbour needs it. ``geometry(t, uv, alpha)``, when given, is
    called with each frame's geometry from the same render, before the frame is yielded."""
    from layercam.scene import render

    geo = ("uv", "alpha") if geometry is not None else ()
    if not ctx.resolved.settings.export.faithful:
        for t in ts:
            reached("export", t)
            out = render.render_frame(model, t, (ctx.clip.H, ctx.clip.W), ("hdr", *geo))
            if geo:
                geometry(t, out["uv"], out["alpha"])
            yield t, out["hdr"], {}
        return
    from layercam.camera.faithful import correction, faithful_log2, merge_weight, neighbour_fill
    from layercam.pipelines.stages import ctx_clip_levels

    lv, frames, T = ctx_clip_levels(ctx), ctx.clip.frames, ctx.clip.T
    static = ctx.resolved.static  # registered by the identity: every frame sees this view
    kept: dict[int, dict] = {}
    # auto: a video from a static camera; not moved along the flow, nor for a bracket's fused view
    # (docs/measurements.md)
    merging = ctx.resolved.settings.export.merge_neighbours == "on"  # auto: a video from a static
                                                                     # camera
                                                                     # (layercam.engine.resolve)

    # auto: a stack's fused view; not videos, whose short and long frames, filtered by their own
    # different noise, flicker (docs/measurements.md)
    denoise = ctx.resolved.settings.export.denoise == "on"  # auto: a stack's fused view (layercam.engine.resolve)

    from layercam.camera.faithful import stack_extremes

    extremes = stack_extremes(frames, lv) if static else None  # once, a frame at a time (it was the
                                                               # whole clip, per frame)

    def corr(t: int) -> dict:
        if t not in kept:
            kept[t] = correction(model, frames[t], t, lv, geometry=bool(geo))
        return kept[t]

    for t in ts:
        reached("export", t)
        neighbours, merge = [], []
        for n in (t - 1, t + 1):
            fl = _flow_to(ctx, t, n) if 0 <= n < T else None
            if fl is not None:
                c = corr(n)
                neighbours.append((c["weight"] * c["delta"], c["weight"], fl))
                if merging:
                    still = np.zeros_like(fl) if static else fl  # a static camera: the same scene
                                                                 # point, whatever the flow says
                    merge.append((c["model_log2_r"] + c["weight"] * c["delta"],
                                  merge_weight(c["exposed"], c["log2_dts"][n], c["log2_dts"]),
                                  still))
        res = faithful_log2(model, frames[t], t, lv, extremes if static else None, corr=corr(t),
                            fill=neighbour_fill(neighbours), merge=merge,
                            clipped=ctx.resolved.settings.export.clipped_everywhere,
                            denoise=denoise)
        if geo:
            geometry(t, kept[t].pop("uv"), kept[t].pop("alpha"))
        for k in [k for k in kept if k < t]:
            del kept[k]
        yield t, np.exp2(res["log2_r"]).astype(np.float32), res["info"]


def _flow_to(ctx: Context, t: int, n: int) -> np.ndarray | None:
    """``(H, W, 2)``: the flow from frame ``t``'s pixels to neighbour ``n = t +- 1``'s where the
    forward-backward check holds, elsewhere the pair's global homography's (a clipped or flat
    region gives the flow nothing to hold on to); None without flow."""
    fl = ctx.flow
    if fl is None or fl.pairs != ctx.clip.T - 1:
        return None
    f, ok = (fl.fw[t], fl.fw_ok[t]) if n == t + 1 else (fl.bw[n], fl.bw_ok[n])
    f = np.asarray(f, np.float32)
    h, w = ctx.clip.H, ctx.clip.W
    if f.shape[:2] != (h, w):
        return None
    hom = np.asarray(fl.homs[min(t, n)], np.float64)
    if not np.isfinite(hom).all() or abs(np.linalg.det(hom)) < 1e-12:  # no homography: the flow alone
        return np.where(np.asarray(ok, bool)[..., None], f, np.nan).astype(np.float32)
    hom = hom if n == t + 1 else np.linalg.inv(hom)
    from layercam.core.geometry import pixel_grid

    xx, yy = (g.astype(np.float64) for g in pixel_grid(h, w))
    q = np.stack([xx, yy, np.ones_like(xx)], -1) @ hom.T
    by_hom = (q[..., :2] / q[..., 2:3] - np.stack([xx, yy], -1)).astype(np.float32)
    return np.where(np.asarray(ok, bool)[..., None], f, by_hom).astype(np.float32)


def faithful_summary(infos: list[dict]) -> dict:
    if not infos or not infos[0]:
        return {"faithful": None}
    return {"faithful": {"mean_weight": round(float(np.mean([i["mean_weight"] for i in infos])), 4),
                         "unseen_share": round(float(np.mean([i["unseen_share"] for i in infos])),
                                               4),
                         "merged_neighbours": any(i.get("merged", False) for i in infos)}}
