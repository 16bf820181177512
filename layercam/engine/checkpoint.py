"""A run's model on disk: save it, load it, rebuild it.

A checkpoint is ``{"format": 3, "state": model state dict, "settings": the run's resolved settings
(:meth:`layercam.engine.resolve.Resolved.to_dict`), "sizes": the sizes derived from the clip, **meta}``
where ``meta`` (``pipelines.stages.model_meta``) holds what the model is built from besides its
settings (bootstrap mappings ``h0``, exposures, the starting irradiance, frame size) and what
describes the run (frame names, fps, task, source, a fused stack's reference view). A checkpoint
of an earlier format is refused with one line: the command that made it, run again, makes it anew.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from layercam.core.errors import LayercamError

FORMAT = 3


def build_model(resolved, meta: dict):
    """The (untrained) model that ``resolved`` (:class:`layercam.engine.resolve.Resolved`) and ``meta``
    describe (``meta["sizes"]``, when there, are the derived sizes it was trained with)."""
    from layercam.engine.model import ImplicitCameraModel

    return ImplicitCameraModel(
        resolved, torch.as_tensor(np.asarray(meta["h0"]), dtype=torch.float32),
        np.asarray(meta["log2_dt"], dtype=np.float32),
        meta.get("exposure_learn", "none"), None if meta.get("phase") is None else np.asarray(meta["phase"]),
        float(meta["init_log2"]), tuple(meta["frame_hw"]), meta.get("sizes"),
    )


def save_run_model(path: Path, model, meta: dict) -> None:
    """Write ``model`` with ``meta`` atomically, with its resolved settings and derived sizes (so a
    later change to a derivation cannot change the shapes a saved run is rebuilt with)."""
    from layercam.io.atomic import atomic_write

    state = {**meta, "format": FORMAT, "state": model.state_dict(),
             "settings": model.resolved.to_dict(), "sizes": dict(model.sizes)}
    atomic_write(path, lambda tmp: torch.save(state, tmp))


def model_from_checkpoint(ck: dict, where: str = "checkpoint"):
    """The model a saved checkpoint dict describes, weights loaded, in eval mode."""
    from layercam.engine.resolve import Resolved

    if ck.get("format") != FORMAT:
        raise LayercamError(f"{where}: saved by an earlier layercam (checkpoint format "
                            f"{ck.get('format', 1)}, this one reads {FORMAT}); "
                            "run the command that made the run again to train it anew")
    model = build_model(Resolved.from_dict(ck["settings"]), ck)
    model.load_state_dict(ck["state"])
    model.eval()
    return model


def load_run_model(run_dir: Path, device: str = "cpu"):
    """``run_dir/checkpoint.pt`` -> ``(model, meta)`` ready to render."""
    path = Path(run_dir) / "checkpoint.pt"
    if not path.exists():
        raise LayercamError(f"{run_dir}: no checkpoint.pt (is this a finished layercam run folder?)")
    try:
        ck = torch.load(path, map_location=device, weights_only=False)
    except Exception as e:  # noqa: BLE001 - any unreadable checkpoint is a user-facing error
        raise LayercamError(f"{path}: cannot read checkpoint ({e.__class__.__name__})") from None
    return model_from_checkpoint(ck, str(path)).to(device), ck
