"""The stages every task is built from: flow -> bootstrap -> train (-> export, in export.py). Between
flow and bootstrap the task measures the clip (``layercam.vision.analyse``) and resolves the settings once
(``layercam.engine.resolve``), which decides the model."""

from __future__ import annotations

import dataclasses

import numpy as np

from layercam.core.errors import LayercamError
from layercam.pipelines.results import BootstrapResult, FlowResult, TrainResult
from layercam.pipelines.runner import Context, Stage


class FlowStage(Stage):
    """Optical flow between neighbours, forward and backward, with consistency masks and the
    per-pair global homography fitted to each forward flow (RANSAC). Computed a pair at a time and
    kept on disk (:mod:`layercam.vision.flow_store`): memory is that of a pair, whatever the clip's length."""

    name = "flow"
    reads = ("flow",)

    def run(self, ctx, out):
        from layercam.engine.resolve import device_of
        from layercam.vision import flow_store

        raft = ctx.cfg.flow.method.startswith("raft")  # a network: where the run trains (before the
                                                       # settings are resolved)
        return flow_store.compute(ctx.clip.frames, out, ctx.cfg.flow, progress=ctx.progress,
                                  device=device_of(ctx.cfg.train.device) if raft else "cpu")

    def load(self, ctx, out, summary):
        """The summary; the arrays opened once into ``ctx.flow`` (None for a single frame)."""
        from layercam.vision import flow_store

        if ctx.flow is None and summary.get("pairs"):
            ctx.flow = flow_store.load(out)
        return FlowResult(summary)

class BootstrapStage(Stage):
    """Starting point of the scene: each layer's mapping into its atlas (chained flow homographies,
    the identity when they move the frames by less than ``STATIC_CORNER_PX``, or the paper's
    identity), the atlas's initial log irradiance, and foreground masks for alpha."""

    name = "bootstrap"
    deps = ("flow",)
    reads = ("scene.bootstrap", "model.layers", "model.tone_mapper", "segment", "static")

    def options(self, ctx):
        """A long clip, or one larger than the flow's grid, is segmented in windows on that grid
        (:func:`layercam.vision.segment.long.foreground_bootstrap_long`): their size (other clips keep their key)."""
        from layercam.vision.segment import long as seg_long

        if ctx.resolved.settings.model.layers > 1 and ctx.flow is not None and seg_long.windowed(
            ctx.clip.T, (ctx.clip.H, ctx.clip.W), ctx.flow.grid):
            return {"windows": [seg_long.SEG_FRAMES, seg_long.SEG_MARGIN]}
        return {}

    def run(self, ctx, out):
        from layercam.camera.tone import initial_log2
        from layercam.core.geometry import atlas_mappings, chain_homographies, middle_frame

        from layercam.vision.flow_store import at_frame_size

        from layercam.vision import segment
        from layercam.vision.segment import long as seg_long

        clip = ctx.clip
        T, H, W = clip.T, clip.H, clip.W
        r = ctx.resolved
        long = r.settings.model.layers > 1 and ctx.flow is not None and seg_long.windowed(T, (H, W),
            ctx.flow.grid)  # on the flow's grid, in windows
        # the motion segmentation reads the flows too
        fl = at_frame_size(ctx.flow, (H, W),
                           None if r.settings.model.layers > 1 and not long else ("homs",))
        ref = middle_frame(T)
        static = r.static  # the flow's chained homographies move no corner by STATIC_CORNER_PX
                           # (layercam.engine.resolve)
        if static:
            bg = np.stack([np.eye(3)] * T)
            how = f"identity: {r.reasons.get('static', 'a static camera')}"
        elif r.settings.scene.bootstrap == "flow" and fl is not None:
            bg = chain_homographies(fl.homs.astype(np.float64), ref)
            how = f"chained flow homographies to frame {ref}"
        else:
            bg = np.stack([np.eye(3)] * T)
            how = "identity"
        h0 = [atlas_mappings(H, W, bg)]
        fg = {}
        cfg = r.settings
        if cfg.segment.detector and (cfg.model.layers == 1 or ctx.masks is not None):
            ctx.say("[bootstrap] segment.detector unused: "
                    f"{'one layer, no foreground' if cfg.model.layers == 1 else '--masks given'}")
        if cfg.model.layers > 1:  # foreground: user masks, else motion segmentation of the flow
            if long:
                fg = seg_long.foreground_bootstrap_long(clip.frames, ctx.flow, out, ctx.masks,
                                                        cfg.segment, progress=ctx.progress)
                if fg["computed"]:
                    g = fg["info"]["grid"]
                    ctx.say(f"[bootstrap] motion segmentation on the flow's {g[1]}x{g[0]} grid, in "
                            f"{fg['info']['windows']} window(s) of at most {seg_long.SEG_FRAMES} "
                            f"frames overlapping by {seg_long.SEG_MARGIN}")
            else:
                fg = segment.foreground_bootstrap(clip.frames, fl, ctx.masks, cfg.segment, progress=ctx.progress)
            h0.append(fg["h0"])
            if fg["computed"]:
                segment.save_masks(out, fg["masks"])
                ctx.say("[bootstrap] motion masks (no --masks given): mean coverage "
                        f"{segment.mask_coverage(fg['masks']).mean():.3f}, saved in {out / 'masks'}")
                if "detector_frames" in fg["info"]:
                    ctx.say("[bootstrap] the detector's instances replaced the motion masks in "
                            f"{fg['info']['detector_frames']} of {T} frames")
        h0 = np.stack(h0)
        init_log2 = initial_log2(clip.frames, ctx.exposures.log2_dt, cfg.model.tone_mapper)  # layercam.camera.tone
        np.save(out / "h0.npy", h0)
        res = {"how": how, "init_log2": init_log2, "layers": int(h0.shape[0]), "static": static}
        if fg:
            res["foreground"] = {"how": fg["how"],
                                 "masks": "motion segmentation" if fg["computed"]
                                 else ("given" if fg["masks"] is not None else "none"),
                                 **fg["info"]}
        return res

    def load(self, ctx, out, summary):
        from layercam.vision.segment import load_masks

        return BootstrapResult(summary, h0=np.load(out / "h0.npy"), init_log2=summary["init_log2"],
                               static=bool(summary["static"]),
                               masks=load_masks(out), foreground=summary.get("foreground"))


class TrainStage(Stage):
    """Fits the model. Its folder keeps ``ckpt.pt`` so that an interrupted run resumes."""

    name = "train"
    deps = ("flow", "bootstrap")
    reads = ("model", "scene", "tone", "blur", "loss", "train", "static")
    all_ranks = True  # data-parallel under torch.distributed (layercam/engine/distributed.py)

    def options(self, ctx):
        """A long clip's alpha grid with slices shared by neighbouring frames
        (:data:`layercam.scene.fields.ALPHA_GRID_CELLS`;
        clips where it changes nothing keep their key); a long clip's later window: the key of
        window 0's camera, held fixed."""
        from layercam.scene.fields import ALPHA_GRID_CELLS, alpha_grid_capped

        out = {}
        clip, cfg = getattr(ctx, "clip", None), ctx.resolved.settings
        if clip is not None and cfg.model.layers > 1 and alpha_grid_capped(cfg.scene, clip.T, (clip.H, clip.W)):
            out["alpha_grid_cells"] = ALPHA_GRID_CELLS
        if getattr(ctx, "camera", None) is not None:
            out["camera"] = ctx.camera["key"]
        return out

    @staticmethod
    def masks(ctx):
        """The masks alpha is fitted to and whether the user gave them: given, else motion."""
        if ctx.masks is not None:
            return ctx.masks, "given"
        return ctx.results["bootstrap"].masks, "motion"

    def run(self, ctx, out):
        import torch

        from layercam.engine import distributed
        from layercam.camera.tone import fit_init_curve
        from layercam.engine.resolve import device_of
        from layercam.engine.sampler import PixelSampler
        from layercam.engine.train import Trainer

        r = ctx.resolved
        cfg = r.settings
        torch.manual_seed(cfg.train.seed)
        model = self.build(ctx)
        if getattr(ctx, "camera", None) is not None:  # layercam.pipelines.windows: window 0's camera, held fixed
            hold_camera(model, ctx.camera)
        elif cfg.model.tone_mapper == "learned":
            fit_init_curve(model.tone, seed=cfg.train.seed)
        masks, source = self.masks(ctx)
        fl = ctx.flow if cfg.model.flow_loss else None
        dev = device_of(cfg.train.device)
        ctx.say(f"[{self.name}] device: {device_line(ctx.cfg.train.device, dev)}")
        model.to(dev)
        callbacks = model.training_callbacks(masks is not None, given=source == "given")
        sampler = PixelSampler(
            ctx.clip.frames, *(fl.fw, fl.bw, fl.fw_ok, fl.bw_ok) if fl is not None else (None,) * 4,
            masks=masks, device=dev, seed=distributed.rank_seed(cfg.train.seed),
        )
        callbacks += [make(model) for make in ctx.train_callbacks]  # e.g. the benchmark's quality probe
        tcfg = dataclasses.replace(cfg.train, batch=distributed.rank_batch(cfg.train.batch))  # each rank's share
        trainer = Trainer(model, sampler, tcfg, out / "ckpt.pt", callbacks, progress=ctx.progress,
                          desc=f"{ctx.task} {self.name}")
        if (out / "ckpt.pt").exists():
            ctx.say(f"[{self.name}] resuming from {out / 'ckpt.pt'}")
        res = trainer.fit()  # its last checkpoint (out / "ckpt.pt") holds the final model
        ctx.model = model.eval()
        losses = [h for h in res.history if "total" in h]
        return {
            "steps": res.steps,
            "processes": distributed.world_size(),
            "device": str(dev),
            "device_asked": ctx.cfg.train.device,
            "model_sizes": model.sizes,
            "seconds_this_session": round(res.seconds, 2),
            "cpu_seconds_this_session": round(res.cpu_seconds, 2),
            "steps_per_s": round((res.steps - res.resumed_from) / max(res.seconds, 1e-9), 2),
            "resumed_from": res.resumed_from,
            "first_loss": losses[0] if losses else None,
            "final_loss": losses[-1] if losses else None,
            "bad_steps": res.bad_steps,
            "events": [h for h in res.history if "event" in h][-20:],
            "log2_dt": model.exposure.values().detach().cpu().tolist(),
            "loss_curve": [[h["step"], h["total"]] for h in losses],
        }

    @staticmethod
    def build(ctx):
        from layercam.engine.checkpoint import build_model

        return build_model(ctx.resolved, model_meta(ctx))

    @classmethod
    def trained(cls, ctx, out):
        """The model a training stage's folder ``out`` holds (its last checkpoint), in eval mode."""
        import torch

        model = cls.build(ctx)
        model.load_state_dict(torch.load(out / "ckpt.pt", map_location="cpu", weights_only=False)["model"])
        return model.eval()

    def load(self, ctx, out, summary):
        """A cached training: the model rebuilt once from its final checkpoint into ``ctx.model``."""
        if ctx.model is None:
            ctx.model = self.trained(ctx, out)
        return TrainResult(summary)


def hold_camera(model, camera: dict) -> None:
    """``model``'s tone mapper (and learned exposure offsets) set to ``camera``'s and held fixed:
    no gradient, and the terms that only shape the tone curve (white balance, monotonicity) off."""
    missing = [k for k in camera["state"] if k not in model.state_dict()]
    if missing:
        raise LayercamError(f"the shared camera does not fit this window's model ({', '.join(missing[:3])})")
    model.load_state_dict(camera["state"], strict=False)
    for name, p in model.named_parameters():
        if name in camera["state"]:
            p.requires_grad_(False)
    model.loss_weights.white_balance = 0.0
    model.loss_weights.gradient = 0.0


FADED_SHARE = 0.25  # the foreground's alpha over less than this share of its masks' area: it lost the object
FADED = "the foreground layer faded in training"  # how the warning begins (layercam edit repeats it)


def faded_foreground(ctx: Context) -> str | None:
    """A warning when a two-layer run's foreground layer lost its object in training: the trained
    alpha (> 0.5, ``export["atlas"]["foreground_share"]``) covers less than ``FADED_SHARE`` of the
    area the masks it was fitted to cover (given or motion masks; a share of the frames,
    over the clip). Alpha that is 0 everywhere satisfies the flow terms, and the plain mask term
    pulls a small object towards the background (docs/measurements.md). None when it did not, or without masks or
    the atlas export (one layer, a run exported before the share was kept)."""
    share = (ctx.results["export"].atlas or {}).get("foreground_share") if "export" in ctx.results else None
    masks, source = TrainStage.masks(ctx)
    if share is None or masks is None:
        return None
    from layercam.vision.segment import mask_coverage

    ref = float(mask_coverage(masks).mean())  # a frame at a time (a long clip's masks are on disk)
    if ref <= 0 or share >= FADED_SHARE * ref:
        return None
    hint = "" if source == "given" else "; --masks gives masks"
    return (f"{FADED}: its alpha holds {share:.2%} of the frames, the {source} masks it started from "
            f"{ref:.2%}; alpha/, the atlases and `layercam edit` miss the object{hint}")


def device_line(asked: str, dev: str) -> str:
    """What a run says about where it trains, e.g. ``cpu (auto: torch sees no CUDA device)``."""
    if asked != "auto":
        return f"{dev} (asked for)"
    import torch

    if dev.startswith("cuda"):
        return f"{dev} (auto: {torch.cuda.get_device_name(0)})"
    return f"{dev} (auto: torch sees no CUDA device)"


def ctx_clip_levels(ctx: Context) -> np.ndarray:
    """The clip's clipping levels (:func:`layercam.core.visibility.clip_levels`), measured once per run
    (a pass over every pixel: seconds on a 1080p clip) and kept in ``ctx.clip_levels``."""
    from layercam.core.visibility import clip_levels

    if ctx.clip_levels is None:
        ctx.clip_levels = clip_levels(ctx.clip.frames)
    return ctx.clip_levels


def model_meta(ctx: Context) -> dict:
    """What :func:`layercam.engine.checkpoint.build_model` needs besides the config, saved with the model."""
    b = ctx.results["bootstrap"]
    e = ctx.exposures
    return {
        "h0": b.h0,
        "log2_dt": np.asarray(e.log2_dt, dtype=np.float32),
        "exposure_learn": e.learn,
        "phase": None if e.phase is None else np.asarray(e.phase),
        "init_log2": b.init_log2,
        "frame_hw": (ctx.clip.H, ctx.clip.W),
        "n_frames": ctx.clip.T,
        "names": list(ctx.clip.names),
        "fps": float(ctx.clip.fps or 24.0),
        "audio": ctx.clip.meta.get("audio"),  # the sound `render` and `edit` carry over (layercam.io.inputs.audio_plan)
        "primaries": (ctx.clip.meta.get("primaries") or {}).get("name", "bt709"),
        "task": ctx.task,
        "source": str(ctx.clip.source),
    }
