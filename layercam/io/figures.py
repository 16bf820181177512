"""Figures drawn with matplotlib without ``pyplot`` (no global figure state: safe under the Agg
backend and in headless kernels): :func:`figure`, and the learned response's :func:`crf_figure`
that every run writes as ``crf.png`` (the other figures of a run: :mod:`layercam.bench.viz`)."""

from __future__ import annotations

import numpy as np

__all__ = ["figure", "crf_figure"]


def figure(nrows: int, ncols: int, cell: tuple[float, float] = (2.2, 2.2), squeeze: bool = False, **kw):
    """A pyplot-free figure and its ``(nrows, ncols)`` axes array."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(cell[0] * ncols, cell[1] * nrows), dpi=90, layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=squeeze, **kw)
    return fig, axes


def crf_figure(z: np.ndarray, curve: np.ndarray, truth: np.ndarray | None = None,
               shift: np.ndarray | None = None, data_range: tuple[float, float] | None = None):
    """Per-channel CRF: one panel per R, G, B with the learned curve ``(K, 3)`` over ``z`` stops and,
    when known, the ground truth ``(K, 3)`` (already aligned, see :func:`layercam.bench.viz.align_crf`; ``shift`` is
    then printed in the legend). ``data_range`` shades the stops that the clip's pixels cover."""
    z = np.asarray(z, dtype=np.float64)
    curve = np.asarray(curve, dtype=np.float64)
    if curve.shape != (z.shape[0], 3):
        raise ValueError(f"crf_figure expects curve (K, 3) over z (K,), got {curve.shape} and {z.shape}")
    fig, axes = figure(1, 3, cell=(2.6, 2.3), sharey=True)
    for c, (name, col) in enumerate(zip("RGB", ("tab:red", "tab:green", "tab:blue"))):
        ax = axes[0, c]
        if data_range is not None:
            ax.axvspan(*data_range, color="0.9", zorder=0, label="seen in the clip")
        ax.plot(z, curve[:, c], color=col, lw=1.6, label="learned")
        if truth is not None:
            lab = "ground truth" + ("" if shift is None else f" ({shift[c]:+.2f} stops)")
            ax.plot(z, np.asarray(truth)[:, c], color="k", ls="--", lw=1.0, label=lab)
            inside = np.ones(len(z), bool) if data_range is None else (z >= data_range[0]) & (z <= data_range[1])
            rmse = float(np.sqrt(np.mean((np.asarray(truth)[inside, c] - curve[inside, c]) ** 2)))
            ax.set_title(f"{name}: RMSE {rmse:.3f}" + ("" if data_range is None else " where seen"), fontsize=8)
        else:
            ax.set_title(name, fontsize=8)
        ax.set_xlabel("log2 r + log2 dt (stops)", fontsize=7)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=6)
        ax.legend(fontsize=6, loc="upper left")
    axes[0, 0].set_ylabel("pixel value", fontsize=7)
    return fig
