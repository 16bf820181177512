"""RAFT optical flow (torchvision's models) from a weights file the user passes; nothing is downloaded."""

from __future__ import annotations

import os

import numpy as np

from layercam.core.errors import LayercamError
from layercam.vision.flow_input import check_frames, normalise_for_flow, pair_progress


def raft_flow(
    frames,
    weights_path: str,
    variant: str | None = None,
    iters: int = 12,
    progress: bool = True,
    device: str | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Forward/backward flow ``(T-1,H,W,2)`` with torchvision RAFT from a local state dict.

    variant: "small", "large", or None to try large then small. The model is built with
    ``weights=None`` and loaded with ``torch.load(path, weights_only=True)``; nothing is
    downloaded. Frames are normalised with ``normalise_for_flow`` (rank) and replicated to RGB,
    padded (replicate) to multiples of 8, at least 128.
    """
    f = check_frames(frames)
    t, h, w = f.shape[:3]
    fw = np.zeros((max(t - 1, 0), h, w, 2), np.float32)
    bw = np.zeros_like(fw)
    model = raft_model(weights_path, variant, device)
    for i, (a, b) in enumerate(pair_progress(raft_pairs(iter(f), model, iters), t - 1, progress, "flow (raft)")):
        fw[i], bw[i] = a, b
    return fw, bw


def raft_model(weights_path: str, variant: str | None = None, device: str | None = None):
    """A torchvision RAFT (eval mode, on ``device``, the CPU by default: a run passes its own) from a
    local state dict (see :func:`raft_flow`); one-line ``LayercamError`` for a missing or wrong file."""
    if not weights_path or not os.path.isfile(weights_path):
        raise LayercamError(f"RAFT weights file not found: {weights_path!r}")
    if variant not in (None, "small", "large"):
        raise LayercamError(f"RAFT variant must be 'small' or 'large', got {variant!r}")
    import torch
    from torchvision.models.optical_flow import raft_large, raft_small

    try:
        state = torch.load(weights_path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - any unreadable file is a user error
        raise LayercamError(f"cannot read RAFT weights {weights_path!r}: {e}") from None
    if isinstance(state, dict) and "state_dict" in state and isinstance(state["state_dict"], dict):
        state = state["state_dict"]
    model = None
    for name in ([variant] if variant else ["large", "small"]):
        m = (raft_large if name == "large" else raft_small)(weights=None, progress=False)
        try:
            m.load_state_dict(state)
        except (RuntimeError, TypeError, KeyError):
            continue
        model = m
        break
    if model is None:
        raise LayercamError(f"{weights_path!r} is not a torchvision RAFT "
                            f"{variant or 'large/small'} state dict")
    dev = torch.device(device or "cpu")
    return model.eval().to(dev)


def raft_pairs(frames, model, iters: int = 12):
    """RAFT flow of each pair of consecutive frames of the iterable ``frames`` (read one at a
    time): yields ``(fw, bw)`` ``(H,W,2)`` float32, as :func:`dis_pairs` does."""
    import torch
    import torch.nn.functional as F

    it = iter(frames)
    first = next(it, None)
    if first is None:
        return
    h, w = np.asarray(first).shape[:2]
    dev = next(model.parameters()).device
    # RAFT needs sides that are multiples of 8 and at least 128 (its correlation pyramid)
    ph, pw = max(128, h + (-h) % 8) - h, max(128, w + (-w) % 8) - w

    def prep(img):
        g = normalise_for_flow(img).astype(np.float32) / 127.5 - 1.0
        x = torch.from_numpy(g)[None, None].repeat(1, 3, 1, 1)
        return F.pad(x, (0, pw, 0, ph), mode="replicate").to(dev)

    with torch.no_grad():
        prev = prep(first)
        for frame in it:
            nxt = prep(frame)
            both = model(torch.cat([prev, nxt]), torch.cat([nxt, prev]), num_flow_updates=iters)[-1]
            both = both[:, :, :h, :w].permute(0, 2, 3, 1).cpu().numpy()
            yield both[0], both[1]
            prev = nxt
