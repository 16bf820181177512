"""Atlas outputs: what each layer of the scene looks like, and how the frames map into it.

Written into the run folder by the export stage's ``atlases`` writer (:mod:`layercam.pipelines.export`):

* ``atlases/layer{k}.exr`` — layer k's atlas as linear irradiance, sampled on a ``res x res`` grid of
  pixel centres over ``uv`` in ``[-1, 1]^2`` (row = v, column = u; ``grid_sample`` with
  ``align_corners=False``).
* ``atlases/layer{k}.png`` — the same atlas as the camera would record it at the clip's middle
  exposure (the learned tone mapper at ``log2_dt_png``), 8-bit RGBA; alpha = coverage, the part of
  the atlas that some frame maps to (weighted by the layer's visibility). This is the image to paint
  on for ``layercam edit``: the edit's colours are read back through the inverse of the same camera.
* ``atlases/layer{k}_uv.mp4`` — each input frame with a checkerboard of the atlas coordinates over
  the pixels where the layer is seen.
* ``atlases/layer{k}_alpha.mp4`` (two layers) — the layer's opacity per frame.
* ``alpha/frame_00000.png`` (two layers) — the foreground's (layer 1) matte per frame, 8-bit: the
  model's alpha averaged with that of the frames up to ``VOTE_REACH`` away, carried along the
  clip's flow where it is consistent (:func:`layercam.vision.motion.flow_vote`), then (> 0.5)
  feathered to the frame's colour edges by the guided filter the finder's masks end with
  (:func:`layercam.vision.segment.edges.guided_matte`; the model's own alpha, which the renders
  composite with, is in ``layer{k}_alpha.mp4``).
* ``atlases/atlas.json`` — grid sizes, the exposure of the PNGs, file names.
"""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path

import numpy as np

from layercam.core.errors import LayercamError
from layercam.core.interrupts import reached
from layercam.pipelines.runner import write_json
from layercam.vision.segment.edges import VOTE_REACH

ATLAS_RES = (32, 2048)  # an exported atlas's side, texels, at least / at most


def atlas_resolution(uv: np.ndarray, weight: np.ndarray, lo: int = ATLAS_RES[0],
                     hi: int = ATLAS_RES[1], pixels: int | None = None) -> int:
    """Atlas grid size at which one frame pixel is about one atlas pixel: from the median spacing of
    neighbouring pixels' ``uv (H, W, 2)`` where the layer is seen (``weight (H, W)`` > 0.5), within
    ``lo..hi`` and, given the clip's ``pixels`` (frames x H x W), at most as many texels as pixels
    see them (more carry nothing: an untrained mapping that squeezes the frames into a corner would
    otherwise ask for the largest atlas)."""
    dx = np.linalg.norm(uv[:, 1:] - uv[:, :-1], axis=-1)
    dy = np.linalg.norm(uv[1:] - uv[:-1], axis=-1)
    on_x = (weight[:, 1:] > 0.5) & (weight[:, :-1] > 0.5)
    on_y = (weight[1:] > 0.5) & (weight[:-1] > 0.5)
    d = np.concatenate([dx[on_x], dy[on_y]]) if (on_x.sum()
                                                 + on_y.sum()) > 8 else np.concatenate([dx.ravel(),
        dy.ravel()])
    step = float(np.median(d)) if d.size else 2.0 / lo
    if pixels:
        hi = max(lo, min(hi, int(np.sqrt(pixels))))
    return int(np.clip(np.ceil(2.0 / max(step, 1e-6)), lo, hi))


def write_rgba_png(path: Path, rgb: np.ndarray, alpha: np.ndarray) -> None:
    """8-bit RGBA PNG from ``rgb (H, W, 3)`` and ``alpha (H, W)`` in [0, 1], atomically."""
    import cv2

    from layercam.io import atomic_write

    q = np.round(np.clip(np.concatenate([rgb[..., ::-1], alpha[..., None]], -1), 0, 1) * 255).astype(np.uint8)

    def _write(tmp: Path) -> None:
        ok, enc = cv2.imencode(".png", np.ascontiguousarray(q))
        if not ok:
            raise LayercamError(f"PNG encoding failed for {path}")
        enc.tofile(str(tmp))

    atomic_write(Path(path), _write)


class AtlasSink:
    """The atlas outputs written as the frames' geometry arrives: ``add(t, uv, alpha)`` for
    ``t = 0, 1, ..., T - 1`` in turn (``uv``: each layer's ``(H, W, 2)``, ``alpha (H, W)`` or None,
    as :func:`~layercam.scene.render.render_frame` returns them), then ``close()`` -> the summary.
    A writer that renders each frame anyway (the HDR frames) feeds it, so the frames' geometry is
    computed once; :func:`export_atlases` renders it for the atlases alone. ``flow``: the clip's
    (the flow stage's arrays, at any size), which the mattes are voted along; without it each matte
    is its own frame's. Holds ``VOTE_REACH + 1`` frames, and the alpha of ``2 VOTE_REACH + 1``."""

    def __init__(self, model, run_dir: Path, frames: np.ndarray, fps: float = 24.0, chunk: int = 65536,
                 flow=None):
        from layercam.core.geometry import middle_frame
        from layercam.io import VideoWriter
        from layercam.scene.render import layer_weights, render_frame
        from layercam.vision.scale import AtFrameSize

        self.model, self.frames, self.chunk = model, frames, chunk
        self.run_dir = Path(run_dir)
        T, H, W = frames.shape[:3]
        self.L = L = model.scene.n_layers
        self.adir = self.run_dir / "atlases"
        self.adir.mkdir(parents=True, exist_ok=True)
        m = render_frame(model, middle_frame(T), (H, W), ("uv", "alpha"), chunk=chunk)
        ws = layer_weights(m["alpha"], L, (H, W))
        self.res = [atlas_resolution(m["uv"][k], ws[k], pixels=T * H * W) for k in range(L)]
        self.acc = [np.zeros(r * r, np.float64) for r in self.res]
        self.two = m["alpha"] is not None
        self.fg: list[float] = []  # per frame, the share of pixels the foreground's alpha holds (> 0.5)
        self.alphas: dict[int, np.ndarray] = {}  # alpha of the frames a matte still to write reads
        self.waiting: dict[int, np.ndarray] = {}  # the frames whose matte is not yet written (read once)
        self.flow = None if not self.two or flow is None or T < 2 else [
            AtFrameSize(flow[k], (H, W)) for k in ("fw", "bw", "fw_ok", "bw_ok")]
        self.reach = VOTE_REACH if self.flow else 0  # a matte is written once the frames it reads are in
        self.next_t, self.open = 0, True
        if self.two:
            (self.run_dir / "alpha").mkdir(exist_ok=True)
        self._videos = contextlib.ExitStack()  # written as the frames arrive: memory of one frame
        self.uv_videos = [self._videos.enter_context(VideoWriter(self.adir / f"layer{k}_uv.mp4",
            fps=fps)) for k in range(L)]
        self.alpha_videos = [self._videos.enter_context(VideoWriter(
            self.adir / f"layer{k}_alpha.mp4", fps=fps)) for k in range(L)] if self.two else []

    def add(self, t: int, uv: list[np.ndarray], alpha: np.ndarray | None) -> None:
        from layercam.scene.render import checker_overlay, layer_weights, splat_add

        if t != self.next_t:
            raise ValueError(f"AtlasSink.add: frame {t} where frame {self.next_t} was due")
        self.next_t += 1
        reached("atlas", t)
        frame = self.frames[t]  # (H, W, 3) float32, read once for the overlays and the matte
        ws = layer_weights(alpha, self.L, frame.shape[:2])
        to8 = lambda x: np.round(np.clip(x, 0, 1) * 255).astype(np.uint8)  # noqa: E731 - videos kept as 8-bit
        for k in range(self.L):
            splat_add(self.acc[k], uv[k], ws[k], self.res[k])
            self.uv_videos[k].add(to8(checker_overlay(frame, uv[k], ws[k])))
            if self.two:
                self.alpha_videos[k].add(to8(ws[k]))
        if self.two:
            self.alphas[t], self.waiting[t] = np.asarray(alpha, np.float32), frame
            self._mattes(t - self.reach)

    def _mattes(self, last: int) -> None:
        """Writes the mattes of the frames up to ``last`` not yet written; forgets the alpha no later
        matte reads."""
        from layercam.io import write_png
        from layercam.vision.motion import flow_vote
        from layercam.vision.segment.edges import guided_matte

        for s in range(len(self.fg), last + 1):
            a = flow_vote(self.alphas, s, *self.flow, reach=self.reach) if self.flow else self.alphas[s]
            matte = guided_matte(self.waiting.pop(s), a)  # zeros where alpha holds nothing
            write_png(self.run_dir / "alpha" / f"frame_{s:05d}.png", matte)
            self.fg.append(float(np.mean(matte > 0.5)))
            self.alphas.pop(s - self.reach, None)  # the frames voted on from here on do not reach it

    def abort(self) -> None:
        """Drops the videos begun (called while an exception ends the export: no partial file is kept)."""
        self.open = False
        self._videos.__exit__(*sys.exc_info())

    def close(self) -> dict:
        from layercam.io import write_exr
        from layercam.scene.render import coverage_from_splat, sample_atlas, tone_map_log2

        T, H, W = self.frames.shape[:3]
        if self.next_t != T:
            raise ValueError(f"AtlasSink.close: {self.next_t} of {T} frames added")
        if self.two:
            self._mattes(T - 1)
        self.open = False
        self._videos.close()
        model, adir, two = self.model, self.adir, self.two
        log2_dt = model.exposure.reference()
        layers = []
        for k in range(self.L):
            log2_r = sample_atlas(model, k, self.res[k], self.chunk)
            cov = coverage_from_splat(self.acc[k], self.res[k])
            write_exr(adir / f"layer{k}.exr", np.exp2(log2_r).astype(np.float32), half=False)
            write_rgba_png(adir / f"layer{k}.png", tone_map_log2(model, log2_r, log2_dt), cov)
            entry = {"layer": k, "res": self.res[k], "exr": f"layer{k}.exr", "png": f"layer{k}.png",
                     "uv_video": f"layer{k}_uv.mp4", "coverage": float(cov.mean())}
            if two:
                entry["alpha_video"] = f"layer{k}_alpha.mp4"
            layers.append(entry)
        info = {
            "layers": layers,
            "uv_grid": "res x res pixel centres over [-1, 1]^2; row = v, column = u (grid_sample, align_corners=False)",
            "log2_dt_png": log2_dt,
            "png_space": "the learned camera (tone mapper) at log2_dt_png; alpha = coverage",
            "exr_space": "linear irradiance (camera dropped)",
            "foreground_alpha": "alpha/frame_*.png" if two else None,
            "frames": T,
            "frame_hw": [H, W],
        }
        write_json(adir / "atlas.json", info)
        return {"layers": [{k: v for k, v in e.items() if k in ("layer", "res", "coverage")}
                           for e in layers], "alpha_mattes": T if two else 0,
                **({"foreground_share": float(np.mean(self.fg))} if two else {})}


def export_atlases(model, run_dir: Path, frames: np.ndarray, fps: float = 24.0, chunk: int = 65536,
                   progress: bool = False, flow=None) -> dict:
    """Writes the files listed in this module's docstring into ``run_dir``, each atlas at
    :func:`atlas_resolution`, rendering each frame's geometry for them (``flow``: as
    :class:`AtlasSink` takes it); returns a summary."""
    from layercam.core.progress import bar as progress_bar
    from layercam.scene.render import render_frame

    T, H, W = frames.shape[:3]
    sink = AtlasSink(model, run_dir, frames, fps, chunk, flow=flow)
    try:
        for t in progress_bar(range(T), desc="atlases", unit="frame", enabled=progress):
            m = render_frame(model, t, (H, W), ("uv", "alpha"), chunk=chunk)
            sink.add(t, m["uv"], m["alpha"])
    except BaseException:
        sink.abort()
        raise
    return sink.close()
