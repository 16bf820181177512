"""Optional: the foreground's masks from a local Mask R-CNN weights file (never downloads).

The motion bootstrap (:func:`layercam.vision.segment.foreground_bootstrap`) finds what moves against the
background; where the flow loses thin or fast parts, or a trunk cuts the object in two, its masks
do too. A detector sees the whole object in each frame but not which object
is the one that moves. So the two are joined: the detector's instances in each frame that lie
mostly in that frame's motion masks replace them (:func:`pick_instances`), and frames where no
instance does keep their motion masks. The layered-atlas papers train on Mask R-CNN masks.

``--set segment.detector=PATH``: a torchvision ``maskrcnn_resnet50_fpn`` or
``maskrcnn_resnet50_fpn_v2`` state dict (e.g. the COCO weights torchvision publishes, fetched by
the user beforehand). Without it nothing here runs.
"""
from __future__ import annotations

import os

import numpy as np

from layercam.core.errors import LayercamError

__all__ = ["load_detector", "detect_instances", "pick_instances"]


def load_detector(path: str, device=None):
    """The Mask R-CNN in ``path`` (v1 or v2 architecture, tried in that order), in eval mode."""
    if not path or not os.path.isfile(path):
        raise LayercamError(f"segment.detector: no such file: {path!r}")
    import torch
    from torchvision.models.detection import maskrcnn_resnet50_fpn, maskrcnn_resnet50_fpn_v2

    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - any unreadable file is a user error
        raise LayercamError(f"segment.detector: cannot read {path!r}: {str(e).splitlines()[0]}") from None
    if isinstance(state, dict) and isinstance(state.get("model"), dict):  # a training checkpoint
        state = state["model"]
    if not isinstance(state, dict) or "roi_heads.mask_predictor.mask_fcn_logits.weight" not in state:
        raise LayercamError(f"segment.detector: {path!r} is not a torchvision Mask R-CNN state dict")
    classes = int(state["roi_heads.mask_predictor.mask_fcn_logits.weight"].shape[0])
    for build in (maskrcnn_resnet50_fpn, maskrcnn_resnet50_fpn_v2):
        model = build(weights=None, weights_backbone=None, num_classes=classes)
        try:
            model.load_state_dict(state)
        except RuntimeError:
            continue
        return model.eval().to(device or "cpu")
    raise LayercamError(f"segment.detector: {path!r} is a Mask R-CNN of neither torchvision "
                        "architecture (maskrcnn_resnet50_fpn, _v2)")


def detect_instances(frames: np.ndarray, path: str, score: float, size: int, progress: bool = False) -> list[dict]:
    """Per frame of ``frames`` ``(T, H, W, 3)`` in [0, 1], the instances scoring at least ``score``:
    ``{"masks": (N, H, W) bool, "scores": (N,), "labels": (N,)}``. Each frame is scaled to the
    clip's mean brightness first (alternating exposures), and the detector sees it with its short
    side at ``size`` pixels (torchvision's default 800: small frames are scaled up). On a GPU when
    torch sees one."""
    import torch

    dev = "cuda" if torch.cuda.is_available() else "cpu"
    model = load_detector(path, dev)
    model.transform.min_size = (int(size),)
    model.transform.max_size = max(int(size) * 1333 // 800, int(size))
    f = np.asarray(frames, np.float32)
    means = f.reshape(len(f), -1).mean(1)
    gains = np.clip(means.mean() / np.maximum(means, 1e-6), 0.25, 4.0)
    out = []
    it = range(len(f))
    if progress:
        from tqdm import tqdm

        it = tqdm(it, total=len(f), desc="detector", unit="frame", leave=False, disable=None)
    with torch.no_grad():
        for t in it:
            x = torch.from_numpy(np.clip(f[t] * gains[t], 0.0, 1.0)).permute(2, 0, 1).contiguous().to(dev)
            d = {k: v.cpu() for k, v in model([x])[0].items()}
            keep = (d["scores"] >= score).numpy()
            out.append({"masks": (d["masks"][:, 0].numpy() > 0.5)[keep],
                        "scores": d["scores"].numpy()[keep], "labels": d["labels"].numpy()[keep]})
    return out


def pick_instances(instances: list[dict], motion: np.ndarray, overlap: float) -> tuple[np.ndarray, dict]:
    """Each frame's mask: the union of its instances of which at least ``overlap`` of the area lies
    in that frame's motion mask; a frame without such an instance keeps its motion mask. Returns
    the masks ``(T, H, W)`` float32 and ``{"detector_frames": frames taken from the detector,
    "detector_instances": instances taken}``."""
    m = np.asarray(motion) > 0.5
    out = m.copy()
    frames = taken = 0
    for t, inst in enumerate(instances):
        masks = np.asarray(inst["masks"], bool).reshape(-1, *m.shape[1:])
        area = masks.sum((1, 2))
        inside = (masks & m[t]).sum((1, 2))
        chosen = (area > 0) & (inside >= overlap * area)
        if chosen.any():
            out[t] = masks[chosen].any(0)
            frames += 1
            taken += int(chosen.sum())
    return out.astype(np.float32), {"detector_frames": frames, "detector_instances": taken}
