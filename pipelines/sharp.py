"""The ``sharp`` writer (``deblur-video``): each frame rendered with the blur generator dropped,
through the tone mapper at the frame's own exposure, kept pixel by pixel where the model re-blurred
reproduces the input (:mod:`layercam.pipelines.view`), the input elsewhere.

Writes ``frames/frame_00000.png`` (the blend), ``trust/frame_00000.png`` (the share of the sharp
render in each pixel: white the render, black the input), ``deblurred.mp4`` and, when exposures
vary, ``hdr/frame_00000.exr`` (the model's sharp render, not blended: the input has no linear
irradiance to blend with); the evaluation reads the blended frames (``deblurred.npy``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from layercam.core.errors import LayercamError
from layercam.core.interrupts import reached
from layercam.io.hdr_set import HdrSet
from layercam.pipelines import media
from layercam.pipelines.runner import Context
from layercam.pipelines.view import blend, check_stride, trust, window_sigma


def sharp_frame(model, t: int, hw: tuple[int, int], frame: np.ndarray, sigma: float, with_hdr: bool) -> dict:
    """Frame ``t``: ``{"ldr": the blend (H, W, 3), "mask": the trust (H, W), "hdr": the sharp
    irradiance or None, "info": the check's summary}``. Without a blur generator the model's render
    is its own re-blurred rendering."""
    from layercam.scene import render

    out = render.render_frame(model, t, hw, ("ldr", "hdr") if with_hdr else ("ldr",))
    sharp = out["ldr"]
    d = check_stride(sigma)
    reblurred = render.render_frame(model, t, hw, ("ldr",), blur=True, centred=True,
                                    stride=d)["ldr"] if model.blur is not None else sharp[::d, ::d]
    if not (np.isfinite(sharp).all() and np.isfinite(reblurred).all()):
        raise LayercamError(f"frame {t}: the model rendered non-finite values; not writing it")
    mask, info = trust(reblurred, frame, sigma, d)
    return {"ldr": blend(sharp, frame, mask), "mask": mask, "hdr": out.get("hdr"), "info": info}


def sharp_writer(ctx: Context, model, dest: Path, cache: Path) -> dict:
    from layercam.io import VideoWriter, write_png

    T, hw = ctx.clip.T, (ctx.clip.H, ctx.clip.W)
    with_hdr = ctx.exposures.varies
    exrs = HdrSet(ctx.resolved.settings.export.half, ctx.say)
    for d in ("frames", "trust") + (("hdr",) if with_hdr else ()):
        (dest / d).mkdir(exist_ok=True)
    kept = np.lib.format.open_memmap(cache / "deblurred.npy", mode="w+", dtype=np.float32,
                                     shape=(T, *hw, 3))  # for the evaluation, on disk
    sigma, infos = window_sigma(ctx), []
    with VideoWriter(dest / "deblurred.mp4", fps=media.fps(ctx), audio=media.audio(ctx)) as video:
        for t in ctx.frames_bar():
            reached("export", t)
            res = sharp_frame(model, t, hw, np.asarray(ctx.clip.frames[t], np.float32), sigma, with_hdr)
            write_png(dest / "frames" / f"frame_{t:05d}.png", res["ldr"], bit_depth=media.png_bits(ctx))
            write_png(dest / "trust" / f"frame_{t:05d}.png", res["mask"])
            kept[t] = res["ldr"]
            video.add(res["ldr"])
            if with_hdr:
                exrs.add(dest / "hdr" / f"frame_{t:05d}.exr", res["hdr"])
            infos.append(res["info"])
    kept.flush()
    del kept
    share = [i["kept"] for i in infos]
    lo = int(np.argmin(share))
    ctx.say(f"[export] the sharp render is kept on {np.mean(share):.0%} of the pixels (frame {lo}: "
            f"{share[lo]:.0%}), where the model "
            "re-blurred reproduces the input within its noise; the input elsewhere (trust/ shows where)"
            + ("; hdr/ is the render" if with_hdr else ""))
    check = {"window_sigma_px": sigma, "kept_share": share, "noise_codes": [i["noise"] for i in infos]}
    return {"frames": int(T), "trust": check, "hdr": with_hdr,
            "hdr_max": exrs.hi if with_hdr else 0.0, "png_bits": media.png_bits(ctx),
            "fps": media.fps(ctx), "sound": media.sound(ctx, video)}


def join_trust(out: Path, dirs: list[Path], joined) -> dict:
    """A windowed run's ``trust/`` (``pipelines/windows.py``): each window's masks (from its export
    folder in ``dirs``) joined as its frames are, ``joined(read)`` yielding ``(t, mask)`` for
    ``read(dir, i)``; ``{"trust": {"kept_share": [...]}}``, or ``{}`` where the windows wrote none."""
    from layercam.io import read_image, write_png

    if not (dirs[0] / "trust").is_dir():
        return {}
    (out / "trust").mkdir(exist_ok=True)
    share = []
    for t, m in joined(lambda d, i: read_image(d / "trust" / f"frame_{i:05d}.png")[..., 0]):
        write_png(out / "trust" / f"frame_{t:05d}.png", np.clip(m, 0.0, 1.0))
        share.append(round(float(np.clip(m, 0.0, 1.0).mean()), 4))
    return {"trust": {"kept_share": share}}
