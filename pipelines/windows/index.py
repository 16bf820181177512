"""A published windowed run as ``render`` and ``edit`` read it: ``windows.json`` (which frames each
window holds, how they are joined), each window's folder and the join's weights."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from layercam.core.errors import LayercamError
from layercam.pipelines.windows.plan import Plan

INDEX = "windows.json"
FOLDER = "windows"  # RUN/windows/w00/: each window's checkpoint.pt, atlases/, psf.json
PER_WINDOW = ("checkpoint.pt", "atlases", "psf.json")
FITS = "fits.npz"  # RUN/windows/fits.npz: each window's fit to each overlap per pixel (w<k>_o<j>), the join's weights


def read_index(run: Path) -> dict | None:
    """A published run's ``windows.json`` (None for a run of one model)."""
    p = Path(run) / INDEX
    if not p.is_file():
        return None
    try:
        return json.loads(p.read_text())
    except (OSError, ValueError):
        raise LayercamError(f"{p} is unreadable") from None


def index_plan(index: dict, run: Path | None = None) -> Plan:
    """The plan a published run was joined with (its windows and, from ``run``'s ``windows/fits.npz``,
    their fits to the overlaps)."""
    fits = {}
    path = Path(run) / FOLDER / FITS if run is not None else None
    if path is not None and path.is_file():
        with np.load(path) as z:
            fits = {tuple(int(v) for v in n[1:].split("_o")): z[n] for n in z.files}
    return Plan([tuple(w["frames"]) for w in index["windows"]], index.get("reason", ""), fits=fits)


def window_folders(run: Path, index: dict) -> list[Path]:
    return [Path(run) / w["folder"] for w in index["windows"]]


def index_gains(index: dict) -> list[float]:
    """Each window's HDR scale relative to window 0's (``hdr_gain``: 1 where the camera is shared)."""
    return [float(w.get("hdr_gain", 1.0)) for w in index["windows"]]


def clip_reference(models, gains: list[float] | None = None) -> float:
    """The clip's reference exposure over windows (each frame once), in window 0's scale: the
    median of every frame's log2 exposure, as ``ExposureField.reference`` is for a single model.
    A window whose irradiance is ``gain`` times window 0's sees its frames at ``log2 gain`` more."""
    gains = gains or [1.0] * len(models)
    vals = [m.exposure.values().detach().float().cpu().numpy() + np.log2(g) for m, g in zip(models, gains)]
    return float(np.median(np.concatenate(vals)))
