"""Figures that look inside a trained run (used by ``notebooks/atlas_visualisation.ipynb``).

Each ``*_figure`` function takes arrays and returns a :class:`matplotlib.figure.Figure` built
without ``pyplot``: no global figure state, safe under the Agg backend and in headless kernels;
Jupyter displays the returned figure, a script saves it with ``fig.savefig(path)``. The arrays come
from a loaded run through the library
(``layercam.scene.render``: ``render_frame``, ``sample_atlas``, ``splat_coverage``, ``checker_overlay``;
``model.tone.curve``, ``model.exposure.values``, ``model.blur.kernels``); nothing here
re-implements the model.

Shapes: frames ``(T, H, W, 3)`` in ``[0, 1]``; alpha ``(T, H, W)``; atlases ``(R, R, 3)`` over
``uv`` in ``[-1, 1]^2`` (row = v, column = u, as :func:`layercam.scene.render.sample_atlas`); a CRF
curve ``(K, 3)`` over ``z (K,)`` stops (``z = log2 r + log2 dt``).

Example:
    >>> import numpy as np
    >>> fig = exposures_figure(np.array([0.0, 2.1, 0.0, 2.1]), truth=np.array([0.0, 2.0, 0.0, 2.0]))
    >>> len(fig.axes)
    1
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from layercam.io.figures import crf_figure, figure as _figure

__all__ = [
    "LAYER_NAMES",
    "align_crf",
    "atlas_figure",
    "alpha_figure",
    "uv_checker_figure",
    "crf_figure",
    "exposures_figure",
    "kernels_figure",
    "sweep_figure",
    "error_overlay",
    "layer_bench_figure",
]

LAYER_NAMES = ("background", "foreground")


def _image_axis(ax, img, title: str | None = None, **kw) -> None:
    ax.imshow(np.clip(np.asarray(img, dtype=np.float32), 0, 1) if np.ndim(img) == 3 else img,
              interpolation="nearest", **kw)
    ax.set_xticks([])
    ax.set_yticks([])
    if title:
        ax.set_title(title, fontsize=8)


def _pick(n: int, k: int) -> list[int]:
    """``k`` evenly spread indices among ``n`` (all of them when ``n <= k``)."""
    if n <= k:
        return list(range(n))
    return sorted({int(round(i)) for i in np.linspace(0, n - 1, k)})


def _layer_name(i: int, n_layers: int) -> str:
    return "single layer" if n_layers == 1 else (LAYER_NAMES[i] if i < len(LAYER_NAMES) else f"layer {i}")


# -- arrays ----------------------------------------------------------------------------------------
def align_crf(z: np.ndarray, curve: np.ndarray, truth: Callable[[np.ndarray], np.ndarray],
              search: float = 24.0, step: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """A ground-truth CRF in the learned curve's units: ``(truth_curve (K, 3), shift (3,) stops)``.

    The learned curve is ``c = T(log2 r + log2 dt)`` with irradiance known only up to a scale per
    channel, so it matches the truth ``c = f(x)`` (``x`` exposed linear value) only after a shift
    ``x = 2^(z + s)``. ``s`` is found per channel by least squares over the part of the learned
    curve that is neither black nor saturated (``0.02 < c < 0.98``), searched on a ``step`` grid
    within ``+-search`` stops. ``truth`` maps ``(N, 3)`` exposed values to ``(N, 3)`` pixel
    values (e.g. ``lambda x: synth.crf_apply(x, "srgb")``).
    """
    z = np.asarray(z, dtype=np.float64)
    curve = np.asarray(curve, dtype=np.float64)
    if curve.shape != (z.shape[0], 3):
        raise ValueError(f"align_crf expects curve (K, 3) over z (K,), got {curve.shape} and {z.shape}")
    shifts = np.arange(-search, search + step / 2, step)
    xs = np.exp2(z[None, :] + shifts[:, None])  # (S, K)
    tv = np.asarray(truth(np.repeat(xs.reshape(-1, 1), 3, axis=1)), dtype=np.float64).reshape(len(shifts), len(z), 3)
    best = np.zeros(3)
    for c in range(3):
        ok = (curve[:, c] > 0.02) & (curve[:, c] < 0.98)
        if not ok.any():
            ok = np.ones_like(ok)
        err = ((tv[:, ok, c] - curve[None, ok, c]) ** 2).mean(axis=1)
        best[c] = shifts[int(np.argmin(err))]
    x = np.exp2(z[:, None] + best[None, :])
    return np.asarray(truth(x), dtype=np.float64).reshape(len(z), 3), best


# -- figures ---------------------------------------------------------------------------------------
def atlas_figure(atlases: Sequence[np.ndarray], coverage: Sequence[np.ndarray] | None = None,
                 camera: Sequence[np.ndarray] | None = None, titles: Sequence[str] | None = None):
    """Each layer's atlas over its ``[-1, 1]^2`` uv square, one row per layer.

    Columns: ``atlases`` (per layer an ``(R, R, 3)`` display image in ``[0, 1]``, e.g. the linear
    atlas through :func:`layercam.scene.render.tonemap_display`); ``coverage`` (per layer ``(R', R')`` in
    ``[0, 1]``, the part of the atlas that some frame sees, :func:`layercam.scene.render.splat_coverage`);
    ``camera`` (per layer ``(R, R, 3)``, the atlas as the camera records it, greyed where
    ``coverage`` is 0: what ``atlases/layer{k}.png`` holds). Absent columns are left out.
    """
    n = len(atlases)
    if n == 0:
        raise ValueError("atlas_figure needs at least one atlas")
    for name, arr in (("coverage", coverage), ("camera", camera)):
        if arr is not None and len(arr) != n:
            raise ValueError(f"atlas_figure: {n} atlases but {len(arr)} {name} images")
    cols = 1 + (coverage is not None) + (camera is not None)
    fig, axes = _figure(n, cols, cell=(2.6, 2.5))
    ext = (-1, 1, 1, -1)  # row = v (downwards), column = u
    for i in range(n):
        name = titles[i] if titles else _layer_name(i, n)
        panels = [(f"{name} atlas (tonemapped)", np.clip(np.asarray(atlases[i], dtype=np.float32), 0, 1), {})]
        cov = None
        if coverage is not None:
            cov = np.clip(np.asarray(coverage[i], dtype=np.float32), 0, 1)
            panels.append((f"{name}: coverage {cov.mean():.0%}", cov, {"cmap": "magma", "vmin": 0, "vmax": 1}))
        if camera is not None:
            img = np.clip(np.asarray(camera[i], dtype=np.float32), 0, 1)
            if cov is not None:
                c = _resize_nearest(cov, img.shape[:2])[..., None]
                img = img * c + (1 - c) * (0.25 + 0.25 * img.mean(-1, keepdims=True))
            panels.append((f"{name} through the camera", img, {}))
        for j, (title, img, kw) in enumerate(panels):
            ax = axes[i, j]
            ax.imshow(img, extent=ext, interpolation="nearest", **kw)
            ax.set_title(title, fontsize=8)
            ax.set_xlabel("u", fontsize=7, labelpad=1)
            ax.set_ylabel("v", fontsize=7, labelpad=1)
            ax.tick_params(labelsize=6)
    return fig


def _resize_nearest(img: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    """``(h, w)`` -> ``(H, W)`` by nearest texel (coverage and atlas grids may differ in size)."""
    h, w = img.shape[:2]
    ys = np.minimum((np.arange(hw[0]) + 0.5) * h / hw[0], h - 1).astype(int)
    xs = np.minimum((np.arange(hw[1]) + 0.5) * w / hw[1], w - 1).astype(int)
    return img[ys][:, xs]


def alpha_figure(alpha: np.ndarray | None, frames: np.ndarray | None = None, max_frames: int = 6,
                 truth: np.ndarray | None = None):
    """Alpha mattes over time: a row of frames (when given), a row of ``alpha (T, H, W)`` and, with
    ``truth (T, H, W)`` (a ground-truth mask), a row of ``alpha - truth`` titled with the IoU of
    ``alpha > 0.5``. A one-layer run (``alpha`` None) gets a figure that says so."""
    if alpha is None:
        fig, axes = _figure(1, 1, cell=(4.0, 1.2))
        axes[0, 0].axis("off")
        axes[0, 0].text(0.5, 0.5, "one layer: no alpha matte (nothing moves on its own)",
             ha="center", va="center", fontsize=9)
        return fig
    from layercam.core.metrics import iou

    alpha = np.asarray(alpha, dtype=np.float32)
    if alpha.ndim != 3:
        raise ValueError(f"alpha_figure expects alpha (T, H, W), got {alpha.shape}")
    if truth is not None and np.shape(truth) != alpha.shape:
        raise ValueError(f"alpha_figure: truth {np.shape(truth)} does not match alpha {alpha.shape}")
    idx = _pick(alpha.shape[0], max_frames)
    rows = [r for r in (("frame", frames), ("alpha", alpha), ("truth", truth)) if r[1] is not None]
    fig, axes = _figure(len(rows), len(idx), cell=(1.8, 1.8))
    for j, t in enumerate(idx):
        for i, (name, arr) in enumerate(rows):
            ax = axes[i, j]
            if name == "frame":
                _image_axis(ax, arr[t], f"frame {t}")
            elif name == "alpha":
                _image_axis(ax, alpha[t], f"alpha, mean {alpha[t].mean():.2f}", cmap="gray", vmin=0, vmax=1)
            else:
                gt = np.asarray(arr[t], dtype=np.float32)
                _image_axis(ax, alpha[t] - gt,
                            f"alpha - true mask\nIoU {iou(alpha[t] > 0.5, gt > 0.5):.2f}",
                            cmap="coolwarm", vmin=-1, vmax=1)
    return fig


def uv_checker_figure(overlays: Sequence[np.ndarray], frame_index: Sequence[int] | None = None, max_frames: int = 6):
    """The UV mapping: per layer, a checkerboard over its atlas warped onto the frames.

    ``overlays``: per layer ``(T, H, W, 3)`` frames with the checkerboard drawn where the layer is
    seen (:func:`layercam.scene.render.checker_overlay`: squares coloured by ``(u, v)``, the frame
    darkened elsewhere). One row per layer, up to ``max_frames`` frames spread over the clip.
    Squares that travel with the content (and with the object as it moves) mean that the mapping
    follows the scene.
    """
    L = len(overlays)
    if L == 0:
        raise ValueError("uv_checker_figure needs at least one layer")
    T = np.asarray(overlays[0]).shape[0]
    idx = _pick(T, max_frames)
    fig, axes = _figure(L, len(idx), cell=(1.8, 1.9))
    for i in range(L):
        for j, t in enumerate(idx):
            label = t if frame_index is None else frame_index[t]
            _image_axis(axes[i, j], overlays[i][t], f"{_layer_name(i, L)}, frame {label}")
    return fig


def exposures_figure(learned: np.ndarray, given: np.ndarray | None = None,
                     truth: np.ndarray | None = None, kind: str = ""):
    """Per-frame log2 exposure: the learned (or given, when fixed) values, the starting values the
    run was given, and the ground truth when known (all relative to frame 0)."""
    learned = np.asarray(learned, dtype=np.float64).reshape(-1)
    t = np.arange(len(learned))
    fig, axes = _figure(1, 1, cell=(max(3.5, 0.35 * len(t)), 2.4))
    ax = axes[0, 0]
    if truth is not None:
        tr = np.asarray(truth, dtype=np.float64).reshape(-1)
        ax.plot(t, tr - tr[0], "s", mfc="none", mec="k", ms=9, label="ground truth")
    if given is not None:
        g = np.asarray(given, dtype=np.float64).reshape(-1)
        ax.plot(t, g - g[0], "x", color="0.5", ms=7, label="start (given / measured)")
    ax.plot(t, learned - learned[0], "o-", color="tab:purple", ms=5, lw=1,
            label="model" + (f" ({kind})" if kind else ""))
    ax.set_xlabel("frame", fontsize=7)
    ax.set_ylabel("log2 exposure rel. frame 0 (EV)", fontsize=7)
    ax.set_xticks(t)
    ax.tick_params(labelsize=6)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6)
    return fig


def kernels_figure(offsets: np.ndarray | None, weights: np.ndarray | None,
                   pixels: np.ndarray | None = None, frame: np.ndarray | None = None,
                   labels: Sequence[str] | None = None, max_offset: float | None = None):
    """The blur generator's PSFs at a few pixels (``model.blur.kernels(xy, t)``).

    ``offsets (M, K, 2)`` pixel displacements (x, y) and ``weights (M, K)`` of each kernel; each
    panel shows the samples as discs of area proportional to the weight, coloured by weight, with
    the pixel's own 1-px patch grid for scale (and, with ``max_offset``, the dotted square the
    offsets are bounded by); ``+`` marks the kernel's weighted centre. ``pixels (M, 2)`` (x, y
    pixel coordinates) are marked on ``frame (H, W, 3)`` in a first panel. A run without a blur
    generator (``offsets`` None) gets
    a figure that says so.
    """
    if offsets is None or weights is None:
        fig, axes = _figure(1, 1, cell=(4.0, 1.2))
        axes[0, 0].axis("off")
        axes[0, 0].text(0.5, 0.5, "no blur generator in this run (blur off): the camera is sharp",
             ha="center", va="center", fontsize=9)
        return fig
    offsets = np.asarray(offsets, dtype=np.float32)
    weights = np.asarray(weights, dtype=np.float32)
    if offsets.ndim != 3 or offsets.shape[2] != 2 or weights.shape != offsets.shape[:2]:
        raise ValueError("kernels_figure expects offsets (M, K, 2) and weights (M, K), got "
                         f"{offsets.shape} and {weights.shape}")
    M, K = weights.shape
    extra = frame is not None
    fig, axes = _figure(1, M + int(extra), cell=(1.9, 2.0))
    if extra:
        ax = axes[0, 0]
        _image_axis(ax, frame, "pixels")
        if pixels is not None:
            for m, (x, y) in enumerate(np.asarray(pixels)):
                ax.plot([x], [y], "o", mfc="none", mec="yellow", ms=7)
                ax.text(x + 1.0, y - 1.0, str(m), color="yellow", fontsize=7)
    n = int(round(np.sqrt(K)))
    grid = np.arange(n) - (n - 1) / 2
    bound = None if max_offset is None else (n - 1) / 2 + float(max_offset)  # where samples can reach
    lim = max(float(np.abs(offsets).max()) + 0.6, 1.6, 0.0 if bound is None else bound + 0.3)
    for m in range(M):
        ax = axes[0, m + int(extra)]
        for g in grid:
            ax.axhline(g, color="0.85", lw=0.5, zorder=0)
            ax.axvline(g, color="0.85", lw=0.5, zorder=0)
        if bound is not None:
            ax.plot([-bound, bound, bound, -bound, -bound], [-bound, -bound, bound, bound, -bound],
                    ls=":", color="0.5", lw=0.8)
        sc = ax.scatter(offsets[m, :, 0], offsets[m, :, 1],
                        s=600 * weights[m] / max(float(weights.max()), 1e-6) + 2, c=weights[m],
                        cmap="viridis", vmin=0, vmax=1, edgecolors="k", linewidths=0.3)
        cx, cy = (weights[m][:, None] * offsets[m]).sum(0)
        ax.plot([cx], [cy], "+", color="red", ms=8)
        ax.set_xlim(-lim, lim)
        ax.set_ylim(lim, -lim)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=6)
        title = labels[m] if labels else f"pixel {m}"
        ax.set_title(f"{title}\ncentre w {weights[m, K // 2]:.2f}", fontsize=7)
    fig.colorbar(sc, ax=axes[0, -1], shrink=0.8, label="weight").ax.tick_params(labelsize=6)
    return fig


def sweep_figure(images: np.ndarray, evs: Sequence[float], title: str = "EV"):
    """An exposure (or focus) sweep: ``images (N, H, W, 3)`` in ``[0, 1]`` side by side, each titled
    with its value in ``evs`` and its share of clipped pixels (a channel above 0.98 or below 0.02)."""
    images = np.asarray(images, dtype=np.float32)
    if images.ndim != 4 or len(evs) != images.shape[0]:
        raise ValueError(f"sweep_figure expects images (N, H, W, 3) and N values, got {images.shape} and {len(evs)}")
    fig, axes = _figure(1, images.shape[0], cell=(1.7, 1.9))
    for j, (img, ev) in enumerate(zip(images, evs)):
        clipped = float(((img > 0.98) | (img < 0.02)).any(-1).mean())
        _image_axis(axes[0, j], img, f"{title} {float(ev):+.1f}\n{clipped:.0%} clipped")
    return fig


def error_overlay(frame: np.ndarray, pred: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Where a mask goes wrong, on the frame ``(H, W, 3)``: ``pred`` and ``truth`` ``(H, W)`` (> 0.5)
    agreeing on the object in green, ``pred`` alone (false positive) in red, ``truth`` alone (missed)
    in blue; the background the two agree on is the frame darkened."""
    p, g = np.asarray(pred) > 0.5, np.asarray(truth) > 0.5
    out = 0.45 * np.clip(np.asarray(frame, dtype=np.float32), 0, 1)
    for sel, col in ((p & g, (0.1, 0.85, 0.1)), (p & ~g, (1.0, 0.1, 0.1)), (~p & g, (0.15, 0.35, 1.0))):
        out[sel] = 0.35 * out[sel] + 0.65 * np.array(col, np.float32)
    return out


def layer_bench_figure(frames: np.ndarray, alpha: np.ndarray, truth: np.ndarray,
                       atlases: Sequence[np.ndarray], boot: np.ndarray | None = None,
                       title: str = "", max_frames: int = 5):
    """One real clip's two-layer run against its true masks: for up to ``max_frames`` frames spread
    over the clip, rows of the frame, the foreground ``alpha (T, H, W)``, the true mask
    ``truth (T, H, W)``, alpha's errors (:func:`error_overlay`, titled with the frame's IoU) and,
    with ``boot`` (the bootstrap's motion masks), their errors too; a last row with each layer's atlas
    (``atlases``: per layer ``(R, R, 3)`` in [0, 1]) and the IoU per frame."""
    from layercam.core.metrics import iou

    frames = np.asarray(frames, dtype=np.float32)
    T, H, W = frames.shape[:3]
    idx = _pick(T, max_frames)
    rows = [("frame", None), ("alpha", alpha), ("true mask", truth),
            ("alpha errors", alpha)] + ([("bootstrap errors", boot)] if boot is not None else [])
    from matplotlib.figure import Figure

    cw = 2.3
    ch = cw * H / W
    fig = Figure(figsize=(cw * len(idx), ch * len(rows) + 2.6 + 0.4 * bool(title)), dpi=90, layout="constrained")
    gs = fig.add_gridspec(len(rows) + 1, len(idx), height_ratios=[ch] * len(rows) + [2.4])
    for i, (name, arr) in enumerate(rows):
        for j, t in enumerate(idx):
            ax = fig.add_subplot(gs[i, j])
            if name == "frame":
                _image_axis(ax, frames[t], f"frame {t}")
            elif name in ("alpha", "true mask"):
                _image_axis(ax, arr[t],
                            f"{name}" + (f", mean {arr[t].mean():.2f}" if name == "alpha" else ""),
                            cmap="gray", vmin=0, vmax=1)
            else:
                _image_axis(ax, error_overlay(frames[t], arr[t], truth[t]),
                            f"{name}: IoU {iou(arr[t] > 0.5, truth[t] > 0.5):.2f}")
    n_at = len(atlases)
    sub = gs[len(rows), :].subgridspec(1, n_at + 1, width_ratios=[1] * n_at + [max(1.5, len(idx) - n_at)])
    for k, at in enumerate(atlases):
        ax = fig.add_subplot(sub[0, k])
        _image_axis(ax, at, f"{_layer_name(k, n_at)} atlas")
    ax = fig.add_subplot(sub[0, n_at])
    ax.plot([iou(a > 0.5, g > 0.5) for a, g in zip(alpha, truth)], "o-", ms=3, label="alpha")
    if boot is not None:
        ax.plot([iou(b > 0.5, g > 0.5) for b, g in zip(boot, truth)], "s--", ms=3, label="bootstrap masks")
    ax.set_ylim(0, 1)
    ax.set_xlabel("frame", fontsize=7)
    ax.set_ylabel("IoU with the true mask", fontsize=7)
    ax.tick_params(labelsize=6)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6)
    if title:
        fig.suptitle(title, fontsize=9)
    return fig
