"""The stages every task is built from: flow -> bootstrap -> train -> export."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from layercam.errors import LayercamError
from layercam.pipelines.runner import Context, Stage, set_aside_previous, write_json


class FlowStage(Stage):
    """Optical flow between neighbours, forward and backward, with consistency masks and the
    per-pair global homography fitted to each forward flow (RANSAC)."""

    name = "flow"
    version = 1

    def key_material(self, ctx):
        return ctx.cfg.section_dict("flow")

    def run(self, ctx, out):
        from layercam import flow

        frames = ctx.clip.frames
        if ctx.clip.T < 2:
            np.savez(out / "flow.npz", fw=np.zeros((0, ctx.clip.H, ctx.clip.W, 2), np.float16))
            return {"pairs": 0}
        method = ctx.cfg.flow.method
        if method == "raft":
            fw, bw = flow.raft_flow(frames, ctx.cfg.flow.raft_weights)
        else:
            fw, bw = flow.compute_flow(frames, method=method, progress=ctx.progress)
        fw_ok = flow.flow_consistency(fw, bw)
        bw_ok = flow.flow_consistency(bw, fw)
        homs = flow.global_homographies(fw)
        np.savez(out / "flow.npz", fw=fw.astype(np.float16), bw=bw.astype(np.float16), fw_ok=fw_ok, bw_ok=bw_ok, homs=homs)
        mag = np.sqrt((fw.astype(np.float32) ** 2).sum(-1))
        return {"pairs": int(len(fw)), "mean_flow_px": float(mag.mean()), "consistent_fraction": float(fw_ok.mean())}

    def load(self, ctx, out, summary):
        return {**summary, "path": str(out / "flow.npz")}


def load_flow(ctx: Context) -> dict | None:
    res = ctx.results.get("flow")
    if not res or not res.get("pairs"):
        return None
    with np.load(res["path"]) as z:
        return {k: z[k] for k in z.files}


# A clip whose chained flow homographies move no frame corner by this much is registered by the
# identity: between frames of different focus or exposure such small homographies are mostly flow
# noise (up to 1 px on an aligned synthetic focus/exposure stack), and a wrong sub-pixel
# registration lets the scene store each frame apart instead of the blur generator explaining it.
STATIC_CORNER_PX = 1.5


class BootstrapStage(Stage):
    """Starting point of the scene: each layer's mapping into its atlas (chained flow homographies,
    the identity when they move the frames by less than ``STATIC_CORNER_PX``, or the paper's
    identity), the atlas's initial log irradiance, and foreground masks for alpha."""

    name = "bootstrap"
    deps = ("flow",)
    version = 3  # 3: reports "static" (identity because nothing moved)

    def key_material(self, ctx):
        m = ctx.cfg.model
        d = {"bootstrap": ctx.cfg.scene.bootstrap, "layers": m.layers, "init_slope": ctx.cfg.tone.init_slope, "tone": m.tone_mapper}
        if m.layers > 1:
            from layercam import segment

            d["foreground"] = {**ctx.cfg.section_dict("segment"), "segment": segment.SEGMENT_VERSION}
        return d

    def run(self, ctx, out):
        from layercam.geometry import atlas_mappings, chain_homographies, max_corner_shift

        clip = ctx.clip
        T, H, W = clip.T, clip.H, clip.W
        fl = load_flow(ctx)
        ref = T // 2
        static = False
        if ctx.cfg.scene.bootstrap == "flow" and fl is not None:
            bg = chain_homographies(fl["homs"].astype(np.float64), ref)
            how = f"chained flow homographies to frame {ref}"
            moved = max_corner_shift(bg, H, W)
            if moved < STATIC_CORNER_PX:  # flow between differently focused/exposed frames: noise
                bg = np.stack([np.eye(3)] * T)
                how = f"identity: the flow homographies move no frame corner by {STATIC_CORNER_PX} px (at most {moved:.2f} px)"
                static = True
        else:
            bg = np.stack([np.eye(3)] * T)
            how = "identity"
        h0 = [atlas_mappings(H, W, bg)]
        fg = {}
        if ctx.cfg.model.layers > 1:  # foreground: user masks, else motion segmentation of the flow
            from layercam import segment

            fg = segment.foreground_bootstrap(clip.frames, fl, ctx.masks, ctx.cfg.segment)
            h0.append(fg["h0"])
            if fg["computed"]:
                segment.save_masks(out, fg["masks"])
                ctx.say(f"[bootstrap] motion masks (no --masks given): mean coverage {fg['masks'].mean():.3f}, saved in {out / 'masks'}")
        h0 = np.stack(h0)
        init_log2 = initial_log2(clip.frames, ctx.exposures.log2_dt, ctx.cfg.tone.init_slope, ctx.cfg.model.tone_mapper)
        np.save(out / "h0.npy", h0)
        res = {"how": how, "init_log2": init_log2, "layers": int(h0.shape[0]), "static": static}
        if fg:
            res["foreground"] = {"how": fg["how"], "masks": "motion segmentation" if fg["computed"] else ("given" if fg["masks"] is not None else "none"), **fg["info"]}
        return res

    def load(self, ctx, out, summary):
        res = {**summary, "h0": np.load(out / "h0.npy")}
        if (out / "masks.npz").exists():
            with np.load(out / "masks.npz") as z:
                res["masks"] = z["masks"].astype(np.float32)
        return res


def initial_log2(frames: np.ndarray, log2_dt: np.ndarray, slope: float, tone: str) -> float:
    """Median log2 irradiance implied by the frames through the starting tone curve."""
    c = np.clip(frames.mean(-1), 0.02, 0.98)
    if tone == "fixed":
        lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
        z = np.log2(np.maximum(lin, 1e-6))
    else:
        z = np.log(c / (1 - c)) / (slope * math.log(2))
    return float(np.median(z - np.asarray(log2_dt, dtype=np.float32)[:, None, None]))


class TrainStage(Stage):
    """Fits the model. Its folder keeps ``ckpt.pt`` so that an interrupted run resumes."""

    name = "train"
    deps = ("flow", "bootstrap")
    version = 3  # 2: alpha trained on bootstrap masks with balanced BCE, tapered (MaskTaper); 3: grid at most one cell per pixel with a blur generator
    all_ranks = True  # data-parallel under torch.distributed (layercam/distributed.py)

    def key_material(self, ctx):
        d = ctx.cfg.section_dict("model", "scene", "tone", "blur", "loss", "train")
        d["train"].pop("checkpoint_every", None)
        d["train"].pop("device", None)
        return d

    def run(self, ctx, out):
        import torch

        from layercam import distributed
        from layercam.camera.tone import fit_init_curve
        from layercam.data import PixelSampler
        from layercam.analyse import resolve_auto
        from layercam.checkpoint import build_model, save_run_model
        from layercam.train import BootstrapPhase, FlowDecay, MaskTaper, Trainer

        boot = ctx.results["bootstrap"]
        cfg = resolve_auto(ctx.cfg, boot.get("static", False), boot["h0"], (ctx.clip.H, ctx.clip.W))
        torch.manual_seed(cfg.train.seed)
        meta = model_meta(ctx)
        model = build_model(cfg, meta)
        if cfg.scene.residual_scale == 0 and ctx.cfg.scene.residual_scale > 0:
            ctx.say("[train] static one-layer scene: per-frame homographies only, no residual warp (scene.residual=on keeps it)")
        if model.blur is not None and ctx.cfg.blur.centre == "auto":
            ctx.say(f"[train] blur PSFs {'centred on their pixel (static scene)' if cfg.blur.centre == 'on' else 'free to shift (moving scene)'}; blur.centre=on|off overrides")
        if cfg.model.tone_mapper == "learned" and not cfg.tone.monotone:
            fit_init_curve(model.tone, cfg.tone.init_slope, seed=cfg.train.seed)
        masks = ctx.masks if ctx.masks is not None else ctx.results["bootstrap"].get("masks")  # given, else motion masks
        if masks is not None and model.scene.alpha is not None:
            model.weights["alpha_mask"] = 1.0
        fl = load_flow(ctx) if cfg.model.flow_loss else None
        dev = resolve_device(cfg.train.device)
        model.to(dev)
        if cfg.train.compile:
            for atlas in model.scene.atlases:
                atlas.compile()
        sampler = PixelSampler(
            ctx.clip.frames, *(fl[k] for k in ("fw", "bw", "fw_ok", "bw_ok")) if fl else (None,) * 4,
            masks=masks, device=dev, seed=distributed.rank_seed(cfg.train.seed),
        )
        callbacks = [FlowDecay(cfg.loss.flow, cfg.loss.flow_decay_end), BootstrapPhase(cfg.train.bootstrap_steps, keys=("bootstrap",)), MaskTaper(cfg.train.bootstrap_steps, cfg.loss.flow_decay_end)]
        callbacks += [make(model) for make in ctx.extra.get("train_callbacks", [])]  # e.g. the benchmark's quality probe
        tcfg = dataclasses.replace(cfg.train, batch=distributed.rank_batch(cfg.train.batch))  # each rank's share
        trainer = Trainer(model, sampler, tcfg, out / "ckpt.pt", callbacks, progress=ctx.progress, desc=f"{ctx.task} train")
        if (out / "ckpt.pt").exists():
            ctx.say(f"[train] resuming from {out / 'ckpt.pt'}")
        res = trainer.fit()
        if distributed.is_main():
            save_run_model(out / "model.pt", model, meta)
        losses = [h for h in res.history if "total" in h]
        return {
            "steps": res.steps,
            "processes": distributed.world_size(),
            "device": str(dev),
            "seconds_this_session": round(res.seconds, 2),
            "steps_per_s": round((res.steps - res.resumed_from) / max(res.seconds, 1e-9), 2),
            "resumed_from": res.resumed_from,
            "first_loss": losses[0] if losses else None,
            "final_loss": losses[-1] if losses else None,
            "bad_steps": res.bad_steps,
            "events": [h for h in res.history if "event" in h][-20:],
            "log2_dt": model.exposure.values().detach().cpu().tolist(),
            "loss_curve": [[h["step"], h["total"]] for h in losses],
        }

    def load(self, ctx, out, summary):
        return {**summary, "model_path": str(out / "model.pt")}


def resolve_device(name: str) -> str:
    import torch

    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda" and not torch.cuda.is_available():
        raise LayercamError("--device cuda asked for, but torch sees no CUDA device")
    return name


def model_meta(ctx: Context) -> dict:
    """What :func:`layercam.checkpoint.build_model` needs besides the config, saved with the model."""
    b = ctx.results["bootstrap"]
    e = ctx.exposures
    return {
        "reasons": dict(ctx.reasons),
        "h0": b["h0"],
        "log2_dt": np.asarray(e.log2_dt, dtype=np.float32),
        "exposure_learn": e.learn,
        "phase": None if e.phase is None else np.asarray(e.phase),
        "init_log2": b["init_log2"],
        "frame_hw": (ctx.clip.H, ctx.clip.W),
        "n_frames": ctx.clip.T,
        "names": list(ctx.clip.names),
        "fps": float(ctx.clip.fps or 24.0),
        "task": ctx.task,
        "source": str(ctx.clip.source),
    }


def load_trained(ctx: Context):
    import torch

    from layercam.checkpoint import model_from_checkpoint

    ck = torch.load(ctx.results["train"]["model_path"], map_location="cpu", weights_only=False)
    return model_from_checkpoint(ck), ck


HDR_VIDEO_OUTPUTS = ["hdr", "preview.mp4", "crf.json", "crf.png", "checkpoint.pt", "report.json"]


class ExportStage(Stage):
    """Writes the run folder: linear HDR EXR per frame, a tonemapped preview, the learned CRF,
    and the checkpoint that ``layercam render`` reads."""

    name = "export"
    deps = ("train",)
    version = 1
    outputs = HDR_VIDEO_OUTPUTS

    def key_material(self, ctx):
        return ctx.cfg.section_dict("export")

    def run(self, ctx, out):
        from layercam.io import write_video
        from layercam.progress import bar as progress_bar
        from layercam.checkpoint import save_run_model
        from layercam.render import render_frame, tonemap_display

        run = ctx.run_dir
        set_aside_previous(run, self.outputs, ctx.keys[self.name], ctx.say)
        model, meta = load_trained(ctx)
        model.to(resolve_device(ctx.cfg.train.device))  # render where it trained (GPU when there is one)
        hw = (ctx.clip.H, ctx.clip.W)
        hdr_dir = run / "hdr"
        hdr_dir.mkdir(exist_ok=True)
        frames = [render_frame(model, t, hw, ctx.cfg.export.chunk)["image"] for t in progress_bar(range(ctx.clip.T), desc="export", unit="frame", enabled=ctx.progress)]
        half = write_hdr_set([hdr_dir / f"frame_{t:05d}.exr" for t in range(len(frames))], frames, ctx.cfg.export.half, ctx.say)
        hdr = np.stack(frames)
        np.save(out / "hdr_stats.npy", np.array([hdr.min(), hdr.max(), hdr.mean()]))
        preview, stats = tonemap_display(hdr)
        fps = ctx.cfg.export.preview_fps or float(ctx.clip.fps or 24.0)
        write_video(run / "preview.mp4", preview, fps=fps)
        model.cpu()
        write_crf(run, model)
        save_run_model(run / "checkpoint.pt", model, meta)
        (run / "export_key.txt").write_text(ctx.keys[self.name])
        return {"frames": int(ctx.clip.T), "hdr_min": float(hdr.min()), "hdr_max": float(hdr.max()), "exr": "half" if half else "float32", "display": stats}


def write_hdr_set(paths: list[Path], images: list[np.ndarray], half: bool, say=None) -> bool:
    """Write linear HDR images as EXR, all of one type: half floats stop at 65504, so a set brighter
    than that is written as float32. Refuses (one line) before writing anything non-finite.
    Returns whether half floats were used."""
    from layercam.io import write_exr

    for p, img in zip(paths, images):
        if not np.isfinite(img).all():
            raise LayercamError(f"{p.name}: the model rendered non-finite irradiance; not writing it")
    peak = max((float(img.max()) for img in images), default=0.0)
    use_half = bool(half) and peak <= 65504.0
    if use_half != bool(half) and say:
        say(f"[export] irradiance reaches {peak:.3g}, beyond half floats: EXRs written as float32")
    for p, img in zip(paths, images):
        write_exr(p, img, half=use_half)
    return use_half


def write_crf(run: Path, model) -> None:
    """``crf.json`` (z = log2 r + log2 dt in stops -> value per channel) and ``crf.png``."""
    import torch

    z = torch.linspace(-12, 12, 241)
    curve = model.tone.curve(z).numpy()
    write_json(run / "crf.json", {"z_stops": z.tolist(), "r": curve[:, 0].tolist(), "g": curve[:, 1].tolist(), "b": curve[:, 2].tolist(), "kind": model.cfg.model.tone_mapper, "exposures_log2": model.exposure.values().detach().tolist()})
    plot_crf(run / "crf.png", z.numpy(), curve)


def plot_crf(path: Path, z: np.ndarray, curve: np.ndarray, truth: np.ndarray | None = None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from layercam.io.atomic import atomic_write

    fig, ax = plt.subplots(figsize=(4.5, 3.2), dpi=100)
    for k, col in enumerate("rgb"):
        ax.plot(z, curve[:, k], color=col, label=f"learned {col.upper()}")
        if truth is not None:
            ax.plot(z, truth[:, k], color=col, ls="--", lw=0.8)
    ax.set_xlabel("log2 irradiance + log2 exposure (stops)")
    ax.set_ylabel("pixel value")
    ax.set_title("camera response")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    atomic_write(Path(path), lambda p: fig.savefig(p))
    plt.close(fig)
