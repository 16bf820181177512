"""One figure per case: the inputs, layercam (each preset run), the classical methods and, where
there is ground truth (or a reference), the error maps in the scores' units. HDR is shown aligned
per channel to the truth through the preview's global tonemap with the truth's statistics
(:func:`~layercam.bench.realsuite.measures.display_hdr`); the Basler clip, which has no truth, through
each method's own tonemap for the whole clip. Saved as compact palette PNGs."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from layercam.bench.realsuite.measures import display_hdr, error_map

__all__ = ["case_figure"]

ERR_MAX = 0.25  # error maps: |mu(pred) - mu(gt)| (both divided by the truth's max) from 0 (black) to this


def _save(fig, path: Path) -> None:
    """Save as an 8-bit palette PNG (a fraction of the RGB size), atomically."""
    import io

    from PIL import Image

    from layercam.io.atomic import atomic_write

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=fig.dpi)
    img = Image.open(buf).convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
    atomic_write(path, lambda p: img.save(p, format="PNG", optimize=True))


def _grid(rows: list[list[tuple[str, np.ndarray | None]]], title: str, cell: float = 2.0):
    """A figure of image cells: ``rows`` of (label, image (H,W,3) in [0,1] or error map (H,W))."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    nr, nc = len(rows), max(len(r) for r in rows)
    h, w = next(im for r in rows for _, im in r if im is not None).shape[:2]
    fig, axes = plt.subplots(nr, nc, figsize=(cell * nc, cell * nr * h / w + 0.35 * nr), dpi=90, squeeze=False)
    for i, r in enumerate(rows):
        for j in range(nc):
            ax = axes[i][j]
            ax.axis("off")
            if j >= len(r) or r[j][1] is None:
                continue
            label, im = r[j]
            if im.ndim == 2:
                ax.imshow(im, cmap="inferno", vmin=0, vmax=ERR_MAX)
            else:
                ax.imshow(np.clip(im, 0, 1))
            ax.set_title(label, fontsize=7)
    fig.suptitle(title, fontsize=8)
    fig.tight_layout()
    return fig, plt


def _label(r: dict) -> str:
    name = r["method"] + (f" {r['preset']}" if r.get("preset") else "")
    if r.get("failed"):
        return name + " (failed)"
    if r.get("psnr") is not None:
        return f"{name}\n{r['psnr']:.2f} dB PSNR ({r.get('gain_db', 0.0):+.2f})"
    if "psnr_mu_fg" in r and r.get("psnr_mu") is not None:
        return f"{name}\n{r['psnr_mu']:.1f} dB (fg {r['psnr_mu_fg']:.1f})"
    if r.get("psnr_mu") is not None:
        return f"{name}\n{r['psnr_mu']:.2f} dB PSNR-mu"
    if r.get("flicker") is not None:
        return f"{name}\nflicker {r['flicker']:.2f}"
    return name


def case_figure(case, case_dir: Path, rows: list[dict], frames: np.ndarray, truth: dict | None,
                preds: dict[str, np.ndarray], path: Path,
                masks: dict[str, np.ndarray] | None = None) -> None:
    """Draw ``case``'s figure into ``path``. ``rows``: the case's table rows; ``preds``: method
    label ("layercam fast", "debevec", ...) -> linear HDR; ``frames``: the inputs as loaded;
    ``masks``: a deblurring run's trust masks ``(T, H, W)`` by the same labels."""
    by_label = {r["method"] + (f" {r['preset']}" if r.get("preset") else ""): r for r in rows}
    labelled = [(_label(by_label[k]) if k in by_label else k, v) for k, v in preds.items()]
    if case.task == "deblur-video":
        fig, plt = _deblur(case, frames, truth, labelled, masks or {})
    elif case.task == "fuse-stack":
        fig, plt = _bracket(case, case_dir, frames, truth, labelled)
    elif truth is not None:
        fig, plt = _composite(case, frames, truth, labelled)
    else:
        fig, plt = _video(case, case_dir, frames, labelled)
    _save(fig, path)
    plt.close(fig)


def _bracket(case, case_dir: Path, frames, truth, labelled):
    mertens = Path(case_dir) / "classical" / "mertens.npy"
    top = [(f"input {i}", f) for i, f in enumerate(frames)]
    if mertens.exists():
        top.append(("Mertens (display-referred,\nnot scored)", np.load(mertens)))
    gt = truth["hdr"]
    kind = "ground truth" if case.truth == "truth" else "reference (not truth)"
    mid = [(kind, display_hdr(gt, gt))] + [(lab, display_hdr(p, gt)) for lab, p in labelled]
    unseen = truth["unseen"].astype(np.float32) * ERR_MAX
    bot = [(f"clipped everywhere\n{100 * truth['unseen'].mean():.1f}% (white)", unseen)] + [
        (f"|error| (0..{ERR_MAX})", error_map(p, gt)) for _, p in labelled]
    return _grid([top, mid, bot], f"{case.name}: {case.about}", cell=2.6)


def _composite(case, frames, truth, labelled):
    import cv2

    gt, fg = truth["hdr"], truth["fg"]
    t0 = len(frames) // 2 - 1
    rows = []
    for t in (t0, t0 + 1):
        outline = display_hdr(gt[t], gt[t]).copy()
        edge = cv2.morphologyEx(fg[t].astype(np.uint8), cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)) > 0
        outline[edge] = (0.0, 1.0, 0.3)
        rows.append([(f"input frame {t}", frames[t]),
                     ("ground truth\n(foreground outlined)", outline)]
                    + [(lab, display_hdr(p[t], gt[t])) for lab, p in labelled])
        rows.append([("", None),
                     (f"clipped everywhere (white)\nframe {t}",
                      truth["unseen"][t].astype(np.float32) * ERR_MAX)]
                    + [(f"|error| frame {t}", error_map(p[t], gt[t])) for _, p in labelled])
    return _grid(rows, f"{case.name}: {case.about}")


def _video(case, case_dir: Path, frames, labelled):
    from layercam.bench.realsuite.jobs import static_pixels
    from layercam.scene.render import tonemap_display

    third = np.linspace(0, len(frames) - 1, 4).round().astype(int)[1:3]
    shown = sorted({int(t) + d for t in third for d in (0, 1)} & set(range(len(frames))))
    disp = []
    for lab, p in labelled:
        _, stats = tonemap_display(p)
        disp.append((lab, [tonemap_display(p[t], stats)[0] for t in shown]))
    rows = [[(f"input frame {t}", frames[t])] + [(lab, d[i]) for lab, d in disp] for i, t in enumerate(shown)]
    _, static = static_pixels(frames, case_dir)
    t = min(shown[0], len(static) - 1)
    rows.append([(f"static pixels of pair {t}-{t + 1} (white)\n{100 * static.mean():.0f}% over all "
                  "pairs", np.repeat(static[t][..., None], 3, -1).astype(np.float32))])
    return _grid(rows, f"{case.name}: {case.about}", cell=2.6)


DIFF_GAIN = 3.0  # deblurring figures: |frame - truth| times this


def _deblur(case, frames, truth, labelled, masks: dict):
    """Two frames (the one the input scores worst on, and the middle one): the input, each method,
    the truth; under each its |difference| from the truth times ``DIFF_GAIN``, then each layercam
    run's trust mask (white: the sharp render written, black: the input)."""
    sharp = truth["sharp"]
    floor = [float(np.mean((f - g) ** 2)) for f, g in zip(frames, sharp)]
    shown = sorted({int(np.argmax(floor)), len(frames) // 2})
    diff = lambda im, t: np.clip(DIFF_GAIN * np.abs(np.clip(im, 0, 1) - sharp[t]), 0, 1)  # noqa: E731
    rows = []
    for t in shown:
        panels = [("input", frames[t])] + [(lab, p[t]) for lab, p in labelled]
        rows.append([(f"{lab.splitlines()[0]} frame {t}", np.clip(im, 0, 1)) for lab, im in panels]
                    + [(f"sharp (truth) frame {t}", sharp[t])])
        rows.append([(f"|{lab.splitlines()[0]} - truth| x{DIFF_GAIN:g}", diff(im, t)) for lab, im in panels]
                    + [(f"trust mask {k} frame {t}\n(white: sharp, black: input)",
                        np.repeat(m[t][..., None], 3, -1)) for k, m in masks.items()])
    rows.insert(0, [(lab, None) for lab, _ in labelled])  # the scores, once, as titles of an empty row
    return _grid([r for r in rows if any(im is not None for _, im in r)],
                 f"{case.name}: {case.about}\n"
                 + "; ".join(lab.replace(chr(10), ": ") for lab, _ in labelled), cell=3.2)
