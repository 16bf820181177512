"""The ``windows`` stage: the windows' outputs joined into the clip's (the package's docstring:
a cross-fade over each overlap weighted per pixel by each window's fit), each window's own outputs
published under ``windows/w00/``, ... and ``windows.json`` written."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np

from layercam.core.interrupts import reached
from layercam.pipelines.runner import Stage, write_json
from layercam.pipelines.windows.index import FITS, FOLDER, INDEX, PER_WINDOW
from layercam.pipelines.windows.plan import Plan, overlap_fits, per_pixel


class WindowsStage(Stage):
    """Joins the windows' outputs into the clip's (the package's docstring)."""

    name = "windows"
    deps = ("flow",)

    def __init__(self, plan: Plan | None = None, results: list[dict] | None = None):
        self.plan, self.results = plan, results or []

    def output_names(self, ctx):
        from layercam.pipelines.export import TASK_WRITERS, WRITERS

        names = [n for w in TASK_WRITERS.get(ctx.task, TASK_WRITERS["hdr-video"]) for n in WRITERS[w][1]]
        return list(dict.fromkeys(names + ["alpha", "crf.json", "crf.png", FOLDER, INDEX]))

    reads = ("export.half", "task")

    def options(self, ctx):
        return {"plan": self.plan.to_dict()["windows"], "exports": [r["keys"]["export"] for r in self.results]}

    def run(self, ctx, out):
        p, res = self.plan, self.results
        dirs = [Path(r["dirs"]["export"]) for r in res]
        summary: dict = {"windows": p.count}
        gains = self._gains(ctx, dirs)
        p.fits = overlap_fits(p, dirs)  # each window's fit to the frames it shares, per pixel: the join's weights
        if (dirs[0] / "hdr").is_dir() and ctx.task != "deblur-video":
            summary.update(self._hdr(ctx, out, dirs, gains))
        if ctx.task == "deblur-video":
            summary.update(self._sharp(ctx, out, dirs, gains, ctx.exposures.varies))
        if (dirs[0] / "alpha").is_dir():
            self._alpha(ctx, out, dirs)
        for n in ("crf.json", "crf.png"):
            if (dirs[0] / n).exists():
                _link(dirs[0] / n, out / n)
        for k, d in enumerate(dirs):
            sub = out / FOLDER / f"w{k:02d}"
            sub.mkdir(parents=True, exist_ok=True)
            for n in PER_WINDOW:
                if (d / n).exists():
                    _link(d / n, sub / n)
        if p.fits:
            with open(out / FOLDER / FITS, "wb") as f:
                np.savez(f, **{f"w{k}_o{j}": e for (k, j), e in p.fits.items()})
        write_json(out / INDEX, {
            "frames": ctx.clip.T,
            "windows": [{"index": k, "frames": list(p.windows[k]), "folder": f"{FOLDER}/w{k:02d}",
                         "hdr_gain": gains[k]} for k in range(p.count)],
            "overlaps": p.overlaps(), "reason": p.reason,
            "camera": "learned by window 0, held fixed in the others"
            if ctx.resolved.settings.model.tone_mapper == "learned" else "the fixed sRGB curve",
            "join": "cross-fade over each overlap weighted per pixel by each window's fit: frame "
                    "t of the overlap [a, b) of windows k and k+1 is (1 - w) x_k + w x_(k+1), w = "
                    "q_(k+1) / (q_k + q_(k+1)), q_k = (1 - f) / e_k, q_(k+1) = f / e_(k+1), f = "
                    "(t - a + 1) / (b - a + 1), e the window's squared error per pixel over the "
                    "overlap's frames (its model through its camera against the input frames; "
                    f"{FOLDER}/{FITS}: e_k of overlap j as w<k>_o<j>; without them the plain "
                    "fade), in linear HDR (hdr/), sharp frames (frames/) and alpha (alpha/)",
        })
        summary["hdr_gains"] = gains
        return summary

    def _gains(self, ctx, dirs: list[Path]) -> list[float]:
        """Window ``k``'s HDR scale relative to window 0's. 1 where the camera is shared (given
        exposures, or learned per phase: window 0's held in the others). Exposures learned per frame
        fix each window's first frame instead, so a window's irradiance may differ from its
        neighbour's by one factor: the median ratio over their overlap (chained from window 0)."""
        gains = [1.0] * self.plan.count
        if ctx.exposures.learn != "all" or not (dirs[0] / "hdr").is_dir():
            return gains
        from layercam.io import read_exr

        for k in range(1, self.plan.count):
            a, b = self.plan.windows[k][0], self.plan.windows[k - 1][1]
            pa, pb = self.plan.windows[k - 1][0], a
            r = []
            for t in range(a, b):
                x = read_exr(dirs[k - 1] / "hdr" / f"frame_{t - pa:05d}.exr")
                y = read_exr(dirs[k] / "hdr" / f"frame_{t - pb:05d}.exr")
                ok = (x > 0) & (y > 0)
                r.append(np.log(x[ok] / y[ok]))
            gains[k] = float(gains[k - 1] * np.exp(np.median(np.concatenate(r)))) if r else gains[k - 1]
        return gains

    def _frames(self, ctx, dirs, gains, read):
        """Each frame of the clip joined: ``(t, sum_k w_k * gain_k * read(dir_k, t - a_k))``, ``w_k``
        per pixel where the plan has the windows' fits (:meth:`Plan.weights`)."""
        for t in range(ctx.clip.T):
            reached("windows", t)
            acc = None
            for k, w in self.plan.weights(t, (ctx.clip.H, ctx.clip.W)):
                x = read(dirs[k], t - self.plan.windows[k][0])
                x = x * per_pixel(np.float32(w * gains[k]), x)
                acc = x if acc is None else acc + x
            yield t, acc

    def _hdr(self, ctx, out, dirs, gains) -> dict:
        from layercam.scene import render
        from layercam.core.colour import REC709, luma
        from layercam.io import VideoWriter, read_exr
        from layercam.pipelines.hdr_frames import FIRST_PASS_PIXELS
        from layercam.pipelines import media
        from layercam.io.hdr_set import HALF_MAX, HdrSet

        def read(d, i):
            return read_exr(d / "hdr" / f"frame_{i:05d}.exr")

        H, W = ctx.clip.H, ctx.clip.W
        step = max(1, int(math.ceil(math.sqrt(H * W / FIRST_PASS_PIXELS))))
        lum, peak = [], 0.0
        for _, hdr in self._frames(ctx, dirs, gains, read):  # the preview's statistics over the joined clip
            lum.append(luma(hdr[::step, ::step], REC709).ravel())
            peak = max(peak, float(hdr.max()))
        stats = render.display_stats(np.concatenate(lum))
        exrs = HdrSet(ctx.resolved.settings.export.half and peak <= HALF_MAX, ctx.say)
        (out / "hdr").mkdir(exist_ok=True)
        with VideoWriter(out / "preview.mp4", fps=media.fps(ctx)) as preview:
            for t, hdr in self._frames(ctx, dirs, gains, read):
                exrs.add(out / "hdr" / f"frame_{t:05d}.exr", hdr)
                preview.add(render.tonemap_display(hdr, stats)[0])
        return {"frames": ctx.clip.T, "hdr_min": exrs.lo, "hdr_max": exrs.hi,
                "exr": "half" if exrs.half else "float32", "display": stats}

    def _sharp(self, ctx, out, dirs, gains, with_hdr: bool) -> dict:
        from layercam.io import VideoWriter, read_exr, write_png
        from layercam.pipelines import media
        from layercam.pipelines.sharp import join_trust
        from layercam.io.hdr_set import HdrSet

        sharp = [np.load(d / "deblurred.npy", mmap_mode="r") for d in dirs]
        T, hw = ctx.clip.T, (ctx.clip.H, ctx.clip.W)
        (out / "frames").mkdir(exist_ok=True)
        kept = np.lib.format.open_memmap(out / "deblurred.npy", mode="w+", dtype=np.float32, shape=(T, *hw, 3))
        index = {d: k for k, d in enumerate(dirs)}
        with VideoWriter(out / "deblurred.mp4", fps=media.fps(ctx)) as video:
            for t, ldr in self._frames(ctx, dirs, [1.0] * len(dirs), lambda d,
                                       i: np.asarray(sharp[index[d]][i], np.float32)):
                ldr = np.clip(ldr, 0.0, 1.0)
                write_png(out / "frames" / f"frame_{t:05d}.png", ldr, bit_depth=media.png_bits(ctx))
                kept[t] = ldr
                video.add(ldr)
        kept.flush()
        del kept, sharp
        res = {"frames": int(T), "hdr": with_hdr, "png_bits": media.png_bits(ctx),
               **join_trust(out, dirs, lambda read: self._frames(ctx, dirs, [1.0] * len(dirs), read))}
        if with_hdr:
            exrs = HdrSet(ctx.resolved.settings.export.half, ctx.say)
            (out / "hdr").mkdir(exist_ok=True)
            for t, hdr in self._frames(ctx, dirs, gains, lambda d, i: read_exr(d / "hdr" / f"frame_{i:05d}.exr")):
                exrs.add(out / "hdr" / f"frame_{t:05d}.exr", hdr)
            res["hdr_max"] = exrs.hi
        return res

    def _alpha(self, ctx, out, dirs) -> None:
        from layercam.io import read_image, write_png

        (out / "alpha").mkdir(exist_ok=True)
        for t, a in self._frames(ctx, dirs, [1.0] * len(dirs), lambda d,
                                 i: read_image(d / "alpha" / f"frame_{i:05d}.png")[..., 0]):
            write_png(out / "alpha" / f"frame_{t:05d}.png", np.clip(a, 0.0, 1.0))

    def load(self, ctx, out, summary):
        from layercam.pipelines.export import kept_arrays
        from layercam.pipelines.results import ExportResult

        return ExportResult(summary, **kept_arrays(out))


def _link(src: Path, dst: Path) -> None:
    """``dst`` a hard-linked copy of ``src`` (file or folder; copies where links fail)."""
    from layercam.pipelines.publish import _link_or_copy

    if dst.is_dir():
        shutil.rmtree(dst)
    elif dst.exists():
        dst.unlink()
    if src.is_dir():
        shutil.copytree(src, dst, copy_function=_link_or_copy)
    else:
        _link_or_copy(str(src), str(dst))


