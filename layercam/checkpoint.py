"""A run's model on disk: save it, load it, rebuild it.

A checkpoint is ``{"format": 2, "state": model state dict, "cfg": the model's own config (every
``auto`` decided, derived sizes filled in), **meta}`` where ``meta`` (:func:`run_meta`) holds what
the model is built from besides its settings (bootstrap mappings ``h0``, exposures, the starting
irradiance, frame size) and what describes the run (frame names, fps, task, source, the analysis's
reasons, a fused stack's reference view).

Older checkpoints (format 1, before the ``model`` config section) stored the analysis's choices as
a separate ``spec`` dict; :func:`upgrade` turns them into the current form, so runs saved then still
load, render and edit.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from layercam.errors import LayercamError

FORMAT = 2


def build_model(cfg, meta: dict):
    """The (untrained) model that ``cfg`` (decided, see :func:`layercam.config.unresolved`) and
    ``meta`` describe."""
    from layercam.model import ImplicitCameraModel

    return ImplicitCameraModel(
        cfg, torch.as_tensor(np.asarray(meta["h0"]), dtype=torch.float32), np.asarray(meta["log2_dt"], dtype=np.float32),
        meta.get("exposure_learn", "none"), None if meta.get("phase") is None else np.asarray(meta["phase"]),
        float(meta["init_log2"]), tuple(meta["frame_hw"]), meta.get("clip_levels"),
    )


def save_run_model(path: Path, model, meta: dict) -> None:
    """Write ``model`` with ``meta`` atomically; ``cfg`` is the model's own (decided, with the sizes
    derived in code filled in), so a later change to a derivation cannot change the shapes a saved
    run is rebuilt with."""
    from layercam.io.atomic import atomic_write

    state = {**meta, "format": FORMAT, "state": model.state_dict(), "cfg": model.cfg.to_dict()}
    atomic_write(path, lambda tmp: torch.save(state, tmp))


def upgrade(ck: dict) -> dict:
    """A checkpoint dict in the current format: a format-1 ``spec`` (layers, tone_mapper, exposures,
    blur "off"|"3x3"|"5x5", max_offset, flow_loss, reasons) becomes the ``model`` section and the
    blur generator's ``n``/``max_offset``; settings that were left ``auto`` then (residual, PSF
    centre) are given the values those runs were trained with; a derived grid size that was not
    stored is read from the saved grid; an alpha field saved before the alpha grid is the positional
    encoding alone."""
    ck = dict(ck)
    cfg = {k: dict(v) if isinstance(v, dict) else v for k, v in ck["cfg"].items()}
    spec = ck.pop("spec", None)
    if spec is not None and "model" not in cfg:
        blur = spec.get("blur", "off")
        cfg["model"] = {"layers": spec["layers"], "tone_mapper": spec["tone_mapper"], "exposures": spec["exposures"], "blur": "off" if blur == "off" else "on", "flow_loss": spec["flow_loss"]}
        b = cfg.setdefault("blur", {})
        b["n"] = int(blur[0]) if blur != "off" else 3
        b["max_offset"] = float(spec.get("max_offset", 5.0))
        ck.setdefault("reasons", spec.get("reasons", {}))
    scene, b = cfg.setdefault("scene", {}), cfg.setdefault("blur", {})
    if scene.get("residual", "auto") == "auto":  # format 1 resolved it into residual_scale
        scene["residual"] = "off" if scene.get("residual_scale", 0.05) == 0 else "on"
    if b.get("centre", "auto") == "auto":  # before blur.centre existed, or off the blur path: free
        b["centre"] = "off"
    if scene.get("encoding", "grid") == "grid" and not scene.get("grid_max_res"):
        sizes = [v.shape[-1] for k, v in ck["state"].items() if k.startswith("scene.atlases.0.enc.grids.")]
        if sizes:
            scene["grid_min_res"], scene["grid_max_res"] = int(min(sizes)), int(max(sizes))
    if "alpha_encoding" not in scene:  # saved before the alpha grid existed: positional encoding only
        scene["alpha_encoding"] = "pe"
    ck["cfg"] = cfg
    ck["format"] = FORMAT
    return ck


def model_from_checkpoint(ck: dict):
    """The model a saved checkpoint dict describes (any format), weights loaded, in eval mode."""
    from layercam.config import config_from_dict

    ck = upgrade(ck)
    model = build_model(config_from_dict(ck["cfg"]), ck)
    model.load_state_dict(ck["state"])
    model.eval()
    return model


def load_run_model(run_dir: Path, device: str = "cpu"):
    """``run_dir/checkpoint.pt`` -> ``(model, meta)`` ready to render (``meta`` upgraded to the
    current format)."""
    path = Path(run_dir) / "checkpoint.pt"
    if not path.exists():
        raise LayercamError(f"{run_dir}: no checkpoint.pt (is this a finished layercam run folder?)")
    try:
        ck = torch.load(path, map_location=device, weights_only=False)
    except Exception as e:  # noqa: BLE001 - any unreadable checkpoint is a user-facing error
        raise LayercamError(f"{path}: cannot read checkpoint ({e.__class__.__name__})") from None
    ck = upgrade(ck)
    return model_from_checkpoint(ck).to(device), ck
