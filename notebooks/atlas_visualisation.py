# ---
# jupyter:
#   jupytext:
#     formats: ipynb,py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#       format_version: '1.3'
#       jupytext_version: 1.19.6
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # Looking inside a layercam run
#
# A trained run is a scene model (one atlas per layer, each with a deformation that maps frames
# into it, and an alpha matte that composites two layers) seen through an implicit camera (a tone
# mapper, per-frame exposures and a blur generator). This notebook draws each part:
#
# 1. each layer's **atlas** (tonemapped) and how much of it the frames see (**alpha coverage**);
# 2. the **alpha mattes** over time;
# 3. the **UV mapping** as a checkerboard warped onto the frames;
# 4. the per-channel **camera response (CRF)**, against the ground truth when it is known;
# 5. the **exposures** of the frames;
# 6. the **blur generator's kernels** at a few pixels;
# 7. an **exposure sweep** re-rendered through the learned camera.
#
# Give a finished run folder in `RUN` (or the environment variable `LAYERCAM_RUN`); left as `None`,
# the notebook trains a tiny run on a synthetic clip first (about half a minute on a laptop CPU),
# where the ground truth is known. The tiny run is forced to two layers and a 3x3 blur generator so
# that every section has something to show; its pictures are 32x32 and its training is short, so
# expect the shapes, not the quality, of a real run.

# %% tags=["parameters"]
import os

RUN = os.environ.get("LAYERCAM_RUN") or None  # a finished run folder (holds checkpoint.pt); None: train a tiny one
CRF_TRUTH = os.environ.get("LAYERCAM_CRF_TRUTH") or None  # a layercam.synth CRF name ("srgb", "mixed", ...) when known
FIGURE_DIR = os.environ.get("LAYERCAM_FIGURE_DIR") or None  # also save every figure as PNG here
ATLAS_RES = None  # atlas grid, texels per side; None: about one texel per frame pixel, as the run's atlases/
SWEEP_EV = [-4, -2, 0, 2, 4]  # exposure sweep, stops from the run's reference exposure

# %%
# %matplotlib inline
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from IPython.display import Image, display

from layercam import synth
from layercam.bench import viz
from layercam.core.geometry import middle_frame
from layercam.engine import checkpoint
from layercam.scene.coords import normalise_xy
from layercam.pipelines.atlas_export import atlas_resolution
from layercam.scene import render

FIGURES = {}  # name -> figure, in the order drawn


def show(name, fig):
    """Display a figure and keep it in FIGURES; with FIGURE_DIR, save it as PNG and show that file."""
    FIGURES[name] = fig
    if not FIGURE_DIR:
        return display(fig)
    path = Path(FIGURE_DIR) / f"{len(FIGURES):02d}_{name}.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    display(Image(filename=str(path)))  # the saved picture: drawn once, not twice


# %% [markdown]
# ## The run
#
# Without a run folder: a synthetic clip (`synth.moving_object`: a textured blob moving on its own
# over a panning HDR background, alternating exposures, a different S-shaped response per channel)
# goes through the `hdr-video` pipeline with the fast preset shrunk to a few seconds of training.
# The object's true masks are passed as a user would pass `--masks` (at 32x32 the motion
# segmentation that runs without masks is unreliable, and this notebook is about looking, not
# segmenting). The exposure ratio is learned (`"alt"` without an EV step), so the exposure plot
# has something to compare with the truth.

# %%
scene = None
if RUN is None:
    from layercam.core.presets import load_config, model_overrides
    from layercam.io import parse_exposures
    from layercam.pipelines.tasks import run_task

    torch.set_num_threads(1)  # tensors this small gain nothing from threads, and a busy machine punishes them
    scene = synth.moving_object(frames=6, size=(32, 32), ev_step=2.0, crf="mixed", seed=0, object_radius=0.25)
    exposures = parse_exposures("alt", scene.clip)  # ratio learned from a measured start
    tiny = [
        "train.steps=100", "train.batch=256", "train.lr=1e-2", "train.bootstrap_steps=50",
        "train.checkpoint_every=1000",
        "scene.grid_levels=3", "scene.atlas_width=16", "scene.deform_width=16",
        "tone.width=16", "flow.method=dis_fast",
    ]
    RUN = Path(tempfile.mkdtemp(prefix="layercam_notebook_")) / "run"
    t0 = time.perf_counter()
    cfg = load_config("fast", tiny + model_overrides(layers=2, blur="3x3", max_offset=2.0))
    run_task("hdr-video", scene.clip, exposures, cfg, RUN, masks=scene.fg_mask.astype(np.float32), progress=False)
    print(f"trained a tiny run in {time.perf_counter() - t0:.1f} s: {RUN}")
    CRF_TRUTH = scene.crf

RUN = Path(RUN)
model, meta = checkpoint.load_run_model(RUN)
report = json.loads((RUN / "report.json").read_text()) if (RUN / "report.json").exists() else {}
T, (H, W) = int(meta["n_frames"]), tuple(meta["frame_hw"])
print(f"{RUN}: task {meta.get('task')}, {T} frames of {W}x{H} from {meta.get('source')}")
from layercam.engine.resolve import format_table

print(format_table(model.resolved))  # what the analysis chose for the run, and why
if report.get("metrics"):
    print("  metrics:", report["metrics"])

# %% [markdown]
# Every frame rendered once (`render.render_frame`, asked for four outputs): linear HDR with the
# camera dropped (`"hdr"`), each layer's atlas coordinates (`"uv"`), the alpha matte (`"alpha"`)
# and the frame as the camera would record it (`"ldr"`, the learned tone mapper at the frame's own
# exposure, sharp).

# %%
renders = [render.render_frame(model, t, (H, W), ("hdr", "uv", "alpha", "ldr")) for t in range(T)]
hdr = np.stack([r["hdr"] for r in renders])  # (T, H, W, 3) linear
uv = [np.stack([r["uv"][k] for r in renders]) for k in range(model.scene.n_layers)]  # per layer (T, H, W, 2)
alpha = None if renders[0]["alpha"] is None else np.stack([r["alpha"] for r in renders])  # (T, H, W)
ldr = np.stack([r["ldr"] for r in renders])
L = len(uv)
visible = [np.stack(w)
           for w in zip(*(render.layer_weights(None if alpha is None else alpha[t], L, (H, W))
                          for t in range(T)))]
_, display_stats = render.tonemap_display(hdr)  # one tonemap for the whole clip and its atlases
print(f"{L} layer(s); irradiance {hdr.min():.3g}..{hdr.max():.3g}")

# %% [markdown]
# ## 1. Atlases and their alpha coverage
#
# Each layer's atlas field sampled on a grid over its `[-1, 1]^2` uv square (as `atlases/` of the
# run holds it, at about one atlas texel per frame pixel), shown three ways: tonemapped like the
# HDR preview; its coverage, the part some frame sees with the layer's opacity (alpha for the
# foreground, 1 - alpha for the background); and through the learned camera at the reference
# exposure, greyed where no frame looks (there the field only extrapolates).

# %%
ref_ev = model.exposure.reference()  # the median of the frames' log2 exposures
atlas_img, camera_img, coverage = [], [], []
for k in range(L):
    res = ATLAS_RES or atlas_resolution(uv[k][middle_frame(T)], visible[k][middle_frame(T)])
    log2_atlas = render.sample_atlas(model, k, res)  # (res, res, 3)
    atlas_img.append(render.tonemap_display(np.exp2(log2_atlas), display_stats)[0])
    camera_img.append(render.tone_map_log2(model, log2_atlas, ref_ev))
    coverage.append(render.splat_coverage(list(uv[k]), list(visible[k]), res))
show("atlases", viz.atlas_figure(atlas_img, coverage, camera_img))

# %% [markdown]
# ## 2. Alpha mattes over time
#
# The foreground's opacity in each frame (white: foreground), under the model's re-render of the
# frame; with a synthetic clip, a third row shows alpha minus the true object mask (red: alpha too
# high, blue: too low).

# %%
truth_mask = None if scene is None or scene.fg_mask is None else scene.fg_mask.astype(np.float32)
show("alpha_mattes", viz.alpha_figure(alpha, ldr, truth=truth_mask))

# %% [markdown]
# ## 3. The UV mapping as a warped checkerboard
#
# A checkerboard drawn on each atlas (squares coloured by their `(u, v)`), looked up through each
# frame's mapping and laid over the frame where the layer is seen (elsewhere the frame is
# darkened); one row per layer. Squares that travel with the content as the camera pans, and with
# the object as it moves, mean that the mapping follows the scene.

# %%
overlays = [np.stack([render.checker_overlay(ldr[t], uv[k][t], visible[k][t], cells=8)
                      for t in range(T)]) for k in range(L)]
show("uv_checkerboard", viz.uv_checker_figure(overlays))

# %% [markdown]
# ## 4. Camera response per channel
#
# The learned tone mapper `T(log2 r + log2 dt)` per channel. The irradiance of a run is known only
# up to a scale, so a known ground-truth CRF (`synth.crf_apply`) is shifted along the stops axis to
# fit the learned curve (the shift is printed in the legend); the shaded span is the range of
# `log2 r + log2 dt` that the clip's pixels actually reach: outside it, the curve is a guess.

# %%
z = torch.linspace(-12, 12, 241)
curve = model.tone.curve(z).numpy()
z_clip = np.log2(np.maximum(hdr, 1e-12)) + model.exposure.values().detach().numpy()[:, None, None, None]
z_range = tuple(np.percentile(z_clip, [1, 99]))
crf_truth, crf_shift = (None, None)
if CRF_TRUTH:
    crf_truth, crf_shift = viz.align_crf(z.numpy(), curve, lambda x: synth.crf_apply(x, CRF_TRUTH))
show("crf", viz.crf_figure(z.numpy(), curve, crf_truth, crf_shift, data_range=z_range))

# %% [markdown]
# ## 5. Exposures
#
# Each frame's log2 exposure as the model uses it, relative to frame 0: learned when the run learns
# them (here one EV ratio between the two alternating phases, from a start measured on the
# frames), otherwise the given values; the ground truth when the clip is synthetic. The frames alone
# cannot tell the true exposures from ratios `k` times larger together with a response curve
# stretched `k` times along the stops axis (and irradiance raised to the power `k`): a short run
# that lands on too large a ratio shows a correspondingly wider curve in section 4.

# %%
learned_ev = model.exposure.values().detach().numpy()
truth_ev = None if scene is None else np.log2(scene.exposure_times)
show("exposures",
     viz.exposures_figure(learned_ev, given=np.asarray(meta["log2_dt"]), truth=truth_ev,
                          kind=model.exposure.learn))
if truth_ev is not None:
    print(f"exposure range: model {np.ptp(learned_ev):.2f} EV, truth {np.ptp(truth_ev):.2f} EV")

# %% [markdown]
# ## 6. The blur generator's kernels
#
# `model.blur.kernels(xy, t)` at four pixels of the middle frame: each of the `n x n` samples is a
# disc at its displacement from the pixel (in pixels; the light grid is the base patch, the dotted
# square the reach of the learned offsets), its area and colour the sample's weight. A sharp
# camera keeps nearly all the weight on the centre sample.

# %%
t_mid = middle_frame(T)
px = np.array([[W // 4, H // 4], [3 * W // 4, H // 4], [W // 4, 3 * H // 4],
               [3 * W // 4, 3 * H // 4]], dtype=np.float32)
offsets = weights = None
if model.blur is not None:
    xy = normalise_xy(torch.from_numpy(px[:, 0]), torch.from_numpy(px[:, 1]), W, H)
    with torch.no_grad():
        offsets, weights = (a.numpy() for a in model.blur.kernels(xy, torch.full((len(px),), t_mid, dtype=torch.long)))
labels = [f"({x:.0f}, {y:.0f}) frame {t_mid}" for x, y in px]
show("blur_kernels",
     viz.kernels_figure(offsets, weights, px, ldr[t_mid], labels,
                        max_offset=float(model.cfg.blur.max_offset)))

# %% [markdown]
# ## 7. Exposure sweep
#
# The middle frame re-rendered through the learned tone mapper at `SWEEP_EV` stops from the run's
# reference exposure (`ref_ev`, the median of its frames'), the blur dropped: what the camera would have
# recorded with a shorter or longer exposure. The titles give each image's share of clipped pixels.

# %%
sweep = np.stack([render.render_frame(model, t_mid, (H, W), "ldr", log2_dt=ref_ev + ev)["ldr"] for ev in SWEEP_EV])
show("exposure_sweep", viz.sweep_figure(sweep, SWEEP_EV))

# %% [markdown]
# ## What was drawn
#
# The figures above, with a last check that every rendered array is finite and that brighter
# exposures never give darker pictures (the tone mapper is meant to be monotone).

# %%
for i, (name, fig) in enumerate(FIGURES.items(), 1):
    print(f"{i}. {name}: {len(fig.axes)} panels")
assert list(FIGURES) == ["atlases", "alpha_mattes", "uv_checkerboard", "crf", "exposures",
                         "blur_kernels", "exposure_sweep"]
assert all(np.isfinite(a).all() for a in (hdr, ldr, sweep, curve, *uv, *atlas_img, *camera_img, *coverage))
assert np.all(np.diff(sweep.mean(axis=(1, 2, 3))) >= -1e-3), "exposure sweep got darker with more exposure"
