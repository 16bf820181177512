"""Rendering a trained model with the camera dropped (sharp linear HDR) or kept (LDR re-renders),
saving and loading a run's model, and the display tonemap used for previews."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from layercam.config import config_from_dict
from layercam.data import pixel_grid
from layercam.errors import LayercamError
from layercam.spec import ModelSpec


@torch.no_grad()
def render_frame(model, t: int, hw: tuple[int, int], chunk: int = 65536, what: str = "hdr", log2_dt: float | None = None, blur: bool = False) -> dict:
    """Render frame ``t`` at ``hw = (H, W)``.

    what "hdr": linear irradiance ``2^log2_r`` (H, W, 3), camera dropped. "ldr": through the tone
    mapper at the frame's own exposure or at ``log2_dt``; ``blur`` keeps the blur generator.
    Returns ``{"image": (H, W, 3), "alpha": (H, W) | None, "uv": [(H, W, 2)]}``.
    """
    h, w = hw
    dev = next(model.parameters()).device
    xy_all = pixel_grid(h, w, dev)
    imgs, alphas, uvs = [], [], []
    for s in range(0, xy_all.shape[0], chunk):
        xy = xy_all[s : s + chunk]
        tt = torch.full((xy.shape[0],), int(t), dtype=torch.long, device=dev)
        if what == "hdr":
            out = model.irradiance(xy, tt)
            img = torch.exp2(out["log2_r"])
        elif what == "ldr":
            with torch.enable_grad() if (blur and model.blur is not None) else torch.no_grad():
                out = model(xy, tt, blur=blur)
            if log2_dt is None:
                img = out["rgb"]
            else:
                img = model.tone_map(out["log2_r_camera"], torch.full_like(out["log2_r"][:, :1], float(log2_dt)))
        else:
            raise ValueError(f"unknown render target {what!r}")
        imgs.append(img.float().cpu())
        if out["alpha"] is not None:
            alphas.append(out["alpha"].float().cpu())
        uvs.append(torch.stack(out["uv"], 0).float().cpu())
    image = torch.cat(imgs).view(h, w, 3).numpy()
    alpha = torch.cat(alphas).view(h, w).numpy() if alphas else None
    uv = torch.cat(uvs, 1).view(-1, h, w, 2).numpy()
    return {"image": image, "alpha": alpha, "uv": list(uv)}


def tonemap_display(hdr: np.ndarray, stats: dict | None = None) -> tuple[np.ndarray, dict]:
    """Global Reinhard (extended) + sRGB for display. ``(..., 3)`` linear -> same shape in ``[0, 1]``.

    ``stats`` (log-average luminance and white point) computed over the whole clip once and reused
    for every frame, so that the preview does not flicker.
    """
    lum = 0.2126 * hdr[..., 0] + 0.7152 * hdr[..., 1] + 0.0722 * hdr[..., 2]
    if stats is None:
        lum_f = lum[np.isfinite(lum)]
        lavg = float(np.exp(np.mean(np.log(np.maximum(lum_f, 1e-8))))) if lum_f.size else 1.0
        white = float(np.percentile(lum_f, 99.9)) / max(lavg, 1e-12) * 0.18 if lum_f.size else 1.0
        stats = {"log_avg": lavg, "white": max(white, 1e-3)}
    scale = 0.18 / max(stats["log_avg"], 1e-12)
    l = lum * scale
    ld = l * (1 + l / stats["white"] ** 2) / (1 + l)
    ratio = np.where(lum > 1e-12, ld / np.maximum(lum, 1e-12), 0.0)
    out = np.clip(hdr * ratio[..., None], 0, 1)
    out = np.where(out <= 0.0031308, 12.92 * out, 1.055 * np.power(out, 1 / 2.4) - 0.055)
    return np.nan_to_num(np.clip(out, 0, 1)).astype(np.float32), stats


# -- a run's model on disk -----------------------------------------------------------------------
def save_run_model(path: Path, model, meta: dict) -> None:
    tmp = Path(path).with_name(Path(path).name + ".tmp")
    torch.save({"state": model.state_dict(), **meta}, tmp)
    tmp.replace(path)


def build_model(cfg, spec: ModelSpec, meta: dict):
    from layercam.model import ImplicitCameraModel

    return ImplicitCameraModel(
        cfg, spec, torch.as_tensor(np.asarray(meta["h0"]), dtype=torch.float32), np.asarray(meta["log2_dt"], dtype=np.float32),
        meta.get("exposure_learn", "none"), None if meta.get("phase") is None else np.asarray(meta["phase"]),
        float(meta["init_log2"]), tuple(meta["frame_hw"]),
    )


def load_run_model(run_dir: Path, device: str = "cpu"):
    """``run_dir/checkpoint.pt`` -> ``(model, meta)`` ready to render."""
    path = Path(run_dir) / "checkpoint.pt"
    if not path.exists():
        raise LayercamError(f"{run_dir}: no checkpoint.pt (is this a finished layercam run folder?)")
    try:
        ck = torch.load(path, map_location=device, weights_only=False)
    except Exception as e:  # noqa: BLE001 - any unreadable checkpoint is a user-facing error
        raise LayercamError(f"{path}: cannot read checkpoint ({e.__class__.__name__})") from None
    cfg = config_from_dict(ck["cfg"])
    spec = ModelSpec(**{k: v for k, v in ck["spec"].items()})
    model = build_model(cfg, spec, ck)
    model.load_state_dict(ck["state"])
    model.eval()
    return model, ck
