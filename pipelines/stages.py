"""The stages every task is built from: flow -> bootstrap -> train (-> export, in export.py). Between
flow and bootstrap the task runs the analysis (``layercam.analyse``), which decides the model."""

from __future__ import annotations

import dataclasses

import numpy as np

from layercam.errors import LayercamError
from layercam.pipelines.runner import Context, Stage


class FlowStage(Stage):
    """Optical flow between neighbours, forward and backward, with consistency masks and the
    per-pair global homography fitted to each forward flow (RANSAC). Computed a pair at a time and
    kept on disk (:mod:`layercam.flow_store`): memory is that of a pair, whatever the clip's length."""

    name = "flow"
    version = 4  # 2: homographies fitted where both frames see well (visibility.pair_visible); "vis" saved; 3: a working size (flow.short_side); 4: on disk, a file per array (flow_store)

    def key_material(self, ctx):
        return ctx.cfg.section_dict("flow")

    def run(self, ctx, out):
        from layercam import flow_store

        summary = flow_store.compute(ctx.clip.frames, out, ctx.cfg.flow, progress=ctx.progress)
        ctx.flow = flow_store.load(out)
        return summary

    def load(self, ctx, out, summary):
        """The cached arrays, opened once into ``ctx.flow`` (None for a single frame)."""
        from layercam import flow_store

        if ctx.flow is None and summary.get("pairs"):
            ctx.flow = flow_store.load(out)
        return summary


from layercam.geometry import STATIC_CORNER_PX  # noqa: E402 - the static-scene threshold (see there)


class BootstrapStage(Stage):
    """Starting point of the scene: each layer's mapping into its atlas (chained flow homographies,
    the identity when they move the frames by less than ``STATIC_CORNER_PX``, or the paper's
    identity), the atlas's initial log irradiance, and foreground masks for alpha."""

    name = "bootstrap"
    deps = ("flow",)
    version = 3  # 3: reports "static" (identity because nothing moved); clips over segment.SEG_FRAMES are segmented in windows (those were not run before)

    def key_material(self, ctx):
        m = ctx.cfg.model
        d = {"bootstrap": ctx.cfg.scene.bootstrap, "layers": m.layers, "init_slope": ctx.cfg.tone.init_slope, "tone": m.tone_mapper}
        if m.layers > 1:
            from layercam import segment

            # the segment settings that differ from their defaults (the defaults are the code's, named
            # by SEGMENT_VERSION: bump it when one changes); refine's are read by the refine stage.
            # Before 2026-11-25 none were keyed (the version overwrote them): a run made again with
            # another segment.* setting reused its masks. Runs at the defaults keep their key.
            seg, default = ctx.cfg.section_dict("segment")["segment"], dataclasses.asdict(segment.SegmentConfig())
            changed = {k: v for k, v in seg.items() if k not in ("refine", "refine_threshold") and v != default[k]}
            d["foreground"] = {"segment": segment.SEGMENT_VERSION, **({"settings": changed} if changed else {})}
            if ctx.flow is not None and segment.windowed(ctx.clip.T, (ctx.clip.H, ctx.clip.W), ctx.flow["fw"].shape[1:3]):
                d["foreground"]["windows"] = [segment.SEG_FRAMES, segment.SEG_MARGIN]  # long or large clips (clips that were not are keyed as before)
        return d

    def run(self, ctx, out):
        from layercam.camera.tone import initial_log2
        from layercam.geometry import atlas_mappings, chain_homographies, max_corner_shift, middle_frame

        from layercam.flow import at_frame_size

        from layercam import segment

        clip = ctx.clip
        T, H, W = clip.T, clip.H, clip.W
        long = ctx.cfg.model.layers > 1 and ctx.flow is not None and segment.windowed(T, (H, W), ctx.flow["fw"].shape[1:3])  # on the flow's grid, in windows
        fl = at_frame_size(ctx.flow, (H, W), None if ctx.cfg.model.layers > 1 and not long else ("homs",))  # the motion segmentation reads the flows too
        ref = middle_frame(T)
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
        if ctx.cfg.segment.detector and (ctx.cfg.model.layers == 1 or ctx.masks is not None):
            ctx.say(f"[bootstrap] segment.detector unused: {'one layer, no foreground' if ctx.cfg.model.layers == 1 else '--masks given'}")
        if ctx.cfg.model.layers > 1:  # foreground: user masks, else motion segmentation of the flow
            if long:
                fg = segment.foreground_bootstrap_long(clip.frames, ctx.flow, out, ctx.masks, ctx.cfg.segment, progress=ctx.progress)
                if fg["computed"]:
                    g = fg["info"]["grid"]
                    ctx.say(f"[bootstrap] motion segmentation on the flow's {g[1]}x{g[0]} grid, in {fg['info']['windows']} window(s) of at most {segment.SEG_FRAMES} frames overlapping by {segment.SEG_MARGIN}")
            else:
                fg = segment.foreground_bootstrap(clip.frames, fl, ctx.masks, ctx.cfg.segment, progress=ctx.progress)
            h0.append(fg["h0"])
            if fg["computed"]:
                segment.save_masks(out, fg["masks"])
                ctx.say(f"[bootstrap] motion masks (no --masks given): mean coverage {segment.mask_coverage(fg['masks']).mean():.3f}, saved in {out / 'masks'}")
                if "detector_frames" in fg["info"]:
                    ctx.say(f"[bootstrap] the detector's instances replaced the motion masks in {fg['info']['detector_frames']} of {T} frames")
        h0 = np.stack(h0)
        init_log2 = initial_log2(clip.frames, ctx.exposures.log2_dt, ctx.cfg.tone.init_slope, ctx.cfg.model.tone_mapper)  # layercam.camera.tone
        np.save(out / "h0.npy", h0)
        res = {"how": how, "init_log2": init_log2, "layers": int(h0.shape[0]), "static": static}
        if fg:
            res["foreground"] = {"how": fg["how"], "masks": "motion segmentation" if fg["computed"] else ("given" if fg["masks"] is not None else "none"), **fg["info"]}
        return res

    def load(self, ctx, out, summary):
        from layercam.segment import load_masks

        res = {**summary, "h0": np.load(out / "h0.npy")}
        masks = load_masks(out)
        if masks is not None:
            res["masks"] = masks
        return res


class TrainStage(Stage):
    """Fits the model. Its folder keeps ``ckpt.pt`` so that an interrupted run resumes."""

    name = "train"
    deps = ("flow", "bootstrap")
    version = 4  # 2: alpha trained on bootstrap masks with balanced BCE, tapered (MaskTaper); 3: grid at most one cell per pixel with a blur generator; 4: sparse grid levels, row-wise Adam (layercam/optim.py)
    all_ranks = True  # data-parallel under torch.distributed (layercam/distributed.py)
    final = True      # the run's model (ctx.model), probed by the benchmark's callbacks; not the refine option's first fit

    def key_material(self, ctx):
        d = ctx.cfg.section_dict("model", "scene", "tone", "blur", "loss", "train")
        d["train"].pop("checkpoint_every", None)
        d["train"].pop("device", None)
        if ctx.cfg.model.layers == 1:
            d["loss"].pop("fg_follow", None)  # a two-layer term: one-layer runs trained before it keep their key
        if ctx.cfg.model.layers == 1 or d["loss"].get("alpha_flow_keep") == 0:
            d["loss"].pop("alpha_flow_keep", None)  # one layer, or the decay as before the setting: those runs keep their key
        if ctx.cfg.model.layers == 1 or not d["loss"].get("mask_anchor"):
            for k in ("mask_anchor", "anchor_band"):
                d["loss"].pop(k, None)  # off (the default) or one layer: runs trained before the anchor keep their key
        if d["loss"].get("robust") in (0.0, "auto"):
            d["loss"].pop("robust")  # MSE, as before the setting: those runs keep their key
        from layercam.scene.fields import ALPHA_GRID_CELLS, alpha_grid_capped

        clip = getattr(ctx, "clip", None)
        if clip is not None and ctx.cfg.model.layers != 1 and alpha_grid_capped(ctx.cfg.scene, clip.T, (clip.H, clip.W)):
            d["alpha_grid_cells"] = ALPHA_GRID_CELLS  # a long clip's frames share the alpha grid's slices (runs where it has no effect keep their key)
        if "refine" in ctx.keys:  # only after the first fit: trained on the refine stage's masks
            d["refined_masks"] = ctx.keys["refine"]
            d["refined_balance"] = "all"  # class-balanced all through, as motion masks (runs before it balanced them during the bootstrap steps only)
        return d

    @staticmethod
    def masks(ctx):
        """The masks alpha is fitted to and whether the user gave them: given, else refined, else motion."""
        if ctx.masks is not None:
            return ctx.masks, "given"
        if "refine" in ctx.results:
            return ctx.results["refine"]["masks"], "refined"
        return ctx.results["bootstrap"].get("masks"), "motion"

    def run(self, ctx, out):
        import torch

        from layercam import distributed
        from layercam.analyse import has_floor_model
        from layercam.camera.tone import fit_init_curve
        from layercam.data import PixelSampler
        from layercam.segment import sure_pixels
        from layercam.train import Trainer

        cfg = self.model_cfg(ctx)
        torch.manual_seed(cfg.train.seed)
        model = self.build(ctx, cfg)
        if cfg.scene.residual_scale == 0 and ctx.cfg.scene.residual_scale > 0:
            ctx.say("[train] static one-layer scene: per-frame homographies only, no residual warp (scene.residual=on keeps it)")
        if cfg.model.layers > 1 and cfg.scene.still_background == "on" and ctx.cfg.scene.still_background == "auto":
            ctx.say("[train] static camera: the background layer held still, no per-frame correction or residual warp (scene.still_background=off frees it)")
        if cfg.train.steps < ctx.cfg.train.steps and cfg.train.steps == cfg.train.min_steps and has_floor_model(cfg):
            ctx.say(f"[train] {cfg.train.steps} steps of {cfg.train.batch} pixels instead of {ctx.cfg.train.steps}: a clip this short trains at the step cap's floor, "
                    f"one model whatever the preset ({cfg.scene.grid_levels} grid levels, atlas width {cfg.scene.atlas_width}; more fit a short stack's noise; "
                    "train.passes_per_frame=0: no cap)")
        elif cfg.train.steps < ctx.cfg.train.steps:
            ctx.say(f"[train] {cfg.train.steps} steps instead of {ctx.cfg.train.steps}: at most {cfg.train.passes_per_frame:g} x {ctx.clip.T} passes over "
                    f"the clip's {ctx.clip.T * ctx.clip.H * ctx.clip.W:,} pixels (more fit a short stack's noise; train.passes_per_frame=0: no cap)")
        if model.blur is not None and ctx.cfg.blur.centre == "auto":
            ctx.say(f"[train] blur PSFs {'centred on their pixel (static scene)' if cfg.blur.centre == 'on' else 'free to shift (moving scene)'}; blur.centre=on|off overrides")
        if cfg.model.tone_mapper == "learned" and not cfg.tone.monotone:
            fit_init_curve(model.tone, cfg.tone.init_slope, seed=cfg.train.seed)
        masks, source = self.masks(ctx)
        fl = ctx.flow if cfg.model.flow_loss else None
        dev = resolve_device(cfg.train.device)
        ctx.say(f"[{self.name}] device: {device_line(cfg.train.device, dev)}")
        model.to(dev)
        if cfg.train.compile:
            for atlas in model.scene.atlases:
                atlas.compile()
        callbacks = model.training_callbacks(masks is not None, given=source == "given")
        sampler = PixelSampler(
            ctx.clip.frames, *(fl[k] for k in ("fw", "bw", "fw_ok", "bw_ok")) if fl else (None,) * 4,
            masks=masks, device=dev, seed=distributed.rank_seed(cfg.train.seed),
            sure=sure_pixels(masks, cfg.loss.anchor_band, _sure_store(masks)) if model.loss_weights.alpha_anchor > 0 else None,  # the model decides (motion masks, two layers)
        )
        if self.final:
            callbacks += [make(model) for make in ctx.train_callbacks]  # e.g. the benchmark's quality probe
        tcfg = dataclasses.replace(cfg.train, batch=distributed.rank_batch(cfg.train.batch))  # each rank's share
        trainer = Trainer(model, sampler, tcfg, out / "ckpt.pt", callbacks, progress=ctx.progress, desc=f"{ctx.task} {self.name}")
        if (out / "ckpt.pt").exists():
            ctx.say(f"[{self.name}] resuming from {out / 'ckpt.pt'}")
        res = trainer.fit()  # its last checkpoint (out / "ckpt.pt") holds the final model
        if self.final:
            ctx.model = model.eval()
        losses = [h for h in res.history if "total" in h]
        return {
            "steps": res.steps,
            "processes": distributed.world_size(),
            "device": str(dev),
            "device_asked": cfg.train.device,
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
    def model_cfg(ctx):
        """The model's own config: ``ctx.cfg`` (analysed) with what the bootstrap decides resolved."""
        from layercam.analyse import resolve_auto

        boot = ctx.results["bootstrap"]
        return resolve_auto(ctx.cfg, boot.get("static", False), boot["h0"], (ctx.clip.H, ctx.clip.W))

    @staticmethod
    def build(ctx, cfg):
        from layercam.checkpoint import build_model

        return build_model(cfg, model_meta(ctx))

    @classmethod
    def trained(cls, ctx, out):
        """The model a training stage's folder ``out`` holds (its last checkpoint), in eval mode."""
        import torch

        model = cls.build(ctx, cls.model_cfg(ctx))
        model.load_state_dict(torch.load(out / "ckpt.pt", map_location="cpu", weights_only=False)["model"])
        return model.eval()

    def load(self, ctx, out, summary):
        """A cached training: the model rebuilt once from its final checkpoint into ``ctx.model``."""
        if ctx.model is None:
            ctx.model = self.trained(ctx, out)
        return summary


class PrefitStage(TrainStage):
    """``segment.refine``: the first fit, on the motion masks, whose background layer the refine
    stage compares each frame with. The same training as the final one; its model is read from
    ``ckpt.pt`` by the refine stage and is not the run's model."""

    name = "prefit"
    version = 1
    final = False

    def load(self, ctx, out, summary):
        return summary


class RefineStage(Stage):
    """``segment.refine``: new foreground masks from the first fit (:func:`layercam.segment.refine_masks`),
    saved as ``masks.npz`` and ``masks/`` PNGs; the train stage fits alpha to them."""

    name = "refine"
    deps = ("bootstrap", "prefit")
    version = 2  # 2: frame and background compared at the clip's mean exposure

    def key_material(self, ctx):
        return {"threshold": ctx.cfg.segment.refine_threshold}

    def run(self, ctx, out):
        import torch

        from layercam import segment
        from layercam.metrics import iou
        from layercam.render import inverse_tone, render_frame, tone_map_log2

        model = TrainStage.trained(ctx, ctx.dirs["prefit"])
        clip = ctx.clip
        # frame and background compared through the camera at one exposure (the clip's mean), so that
        # a threshold in pixel values means the same in a short and a long frame: at each frame's own
        # exposure the alternating short frames' masks came out smaller (synthetic moving object,
        # seed 2: 1305, 1061, 1220, 1068, ... pixels against 1161-1173 true)
        with torch.no_grad():
            dts = model.exposure.values().float().cpu().numpy()
        common = float(dts.mean())
        seen, bg, alpha = [], [], []
        for t in range(clip.T):  # render_frame, tone_map_log2 and inverse_tone run without gradients
            r = render_frame(model, t, (clip.H, clip.W), what=("layers", "alpha"))
            bg.append(tone_map_log2(model, r["layers"][0], common))
            seen.append(tone_map_log2(model, inverse_tone(model, clip.frames[t], float(dts[t])), common))
            alpha.append(r["alpha"])
        masks = segment.refine_masks(np.stack(seen), np.stack(bg), np.stack(alpha), ctx.cfg.segment.refine_threshold)
        segment.save_masks(out, masks)
        boot = ctx.results["bootstrap"].get("masks")
        agree = float(np.mean([iou(a, b > 0.5) for a, b in zip(masks, boot)]))  # refine_wanted: the bootstrap made masks
        ctx.say(f"[refine] masks from the first fit's background residual: mean coverage {masks.mean():.3f} (motion masks {segment.mask_coverage(boot).mean():.3f}, IoU with them {agree:.3f}), saved in {out / 'masks'}")
        return {"coverage": float(masks.mean()), "iou_with_motion_masks": agree}

    def load(self, ctx, out, summary):
        from layercam.segment import load_masks

        return {**summary, "masks": load_masks(out)}


def _sure_store(masks):
    """Where :func:`layercam.segment.sure_pixels` writes for ``masks``: beside them on disk (an
    unlinked temporary file) when they are kept on disk, else in memory (None)."""
    from layercam.io.frames import DiskArray, TempArray

    return TempArray(np.bool_, masks.shape, masks.path.parent) if isinstance(masks, DiskArray) else None


def refine_wanted(ctx) -> bool:
    """``segment.refine`` applies: two layers whose masks came from the motion segmentation."""
    boot = ctx.results.get("bootstrap", {})
    return bool(ctx.cfg.segment.refine) and ctx.cfg.model.layers > 1 and ctx.masks is None and boot.get("masks") is not None


def resolve_device(name: str) -> str:
    """``train.device`` -> the device to use: "auto" is CUDA when torch sees a GPU, else the CPU."""
    import torch

    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda" and not torch.cuda.is_available():
        raise LayercamError("--device cuda asked for, but torch sees no CUDA device")
    return name


def device_line(asked: str, dev: str) -> str:
    """What a run says about where it trains, e.g. ``cpu (auto: torch sees no CUDA device)``."""
    if asked != "auto":
        return f"{dev} (asked for)"
    import torch

    if dev.startswith("cuda"):
        return f"{dev} (auto: {torch.cuda.get_device_name(0)})"
    return f"{dev} (auto: torch sees no CUDA device)"


def ctx_clip_levels(ctx: Context) -> np.ndarray:
    """The clip's clipping levels (:func:`layercam.visibility.clip_levels`), measured once per run
    (a pass over every pixel: seconds on a 1080p clip) and kept in ``ctx.results``."""
    from layercam.visibility import clip_levels

    if "clip_levels" not in ctx.results:
        ctx.results["clip_levels"] = clip_levels(ctx.clip.frames)
    return ctx.results["clip_levels"]


def model_meta(ctx: Context) -> dict:
    """What :func:`layercam.checkpoint.build_model` needs besides the config, saved with the model."""
    b = ctx.results["bootstrap"]
    e = ctx.exposures
    return {
        "clip_levels": ctx_clip_levels(ctx).tolist(),
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
