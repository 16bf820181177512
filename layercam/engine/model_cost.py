"""The model's own cost, before any frame is seen: its parameters by part, counted on PyTorch's meta
device (:func:`model_parts`), and what a training step keeps per sample (:func:`kept_for_backward`,
measured on a small stand-in of the model; :func:`floats_per_sample`, which part that is most for).
:mod:`layercam.engine.estimate` scales them by the clip and the stages."""

from __future__ import annotations

import numpy as np

from layercam.core.errors import LayercamError

PROBE = (1024, 2048)     # samples of the two forward passes that measure what a training step keeps (kept_for_backward)
PROBE_HW = 64            # the stand-in clip's side (px) and its frames (below): what a sample keeps does not depend
PROBE_FRAMES = 4         # on the clip's size, only on the model's structure


def identity_meta(r, frames: int, hw: tuple[int, int], extent: float | None = None) -> dict:
    """What :func:`~layercam.engine.checkpoint.build_model` needs to build the model ``r`` (resolved)
    for ``frames`` frames of ``hw`` before any frame is seen: identity mappings, and the sizes of
    an atlas whose frames span ``extent`` frame pixels across (None: the identity's own)."""
    from layercam.core.geometry import atlas_mappings, atlas_pixels
    from layercam.scene.layered import sizes_for_extent

    m = r.settings.model
    h0 = np.stack([atlas_mappings(*hw, np.repeat(np.eye(3)[None], frames, 0))] * int(m.layers))
    px = atlas_pixels(h0, hw) if extent is None else extent
    return {"h0": h0, "log2_dt": np.zeros(frames, np.float32), "init_log2": 0.0, "frame_hw": hw,
            "sizes": sizes_for_extent(px, hw, fine=m.blur == "on" or (r.static and m.layers == 1))}


def model_parts(r, frames: int, hw: tuple[int, int], extent: float) -> dict:
    """Parameters by part of the model ``r`` (resolved) builds for ``frames`` frames of ``hw`` and
    an atlas ``extent`` frame pixels across, counted on the meta device."""
    import torch

    from layercam.engine.checkpoint import build_model

    H, W = hw
    meta = identity_meta(r, frames, hw, extent)  # on the host: the meta device holds no values
    try:
        with torch.device("meta"):
            model = build_model(r, meta)
    except ValueError as e:  # a model these frames cannot hold (two layers of 1x1 frames): said before the work
        raise LayercamError(f"the model asked for does not fit {W}x{H} frames: {e}") from None
    parts: dict[str, int] = {}
    for name, p in model.named_parameters():
        parts[_part(name)] = parts.get(_part(name), 0) + p.numel()
    return parts


def _part(name: str) -> str:
    if ".alpha.grid" in name:
        return "alpha grid"
    if ".alpha." in name:
        return "alpha MLP"
    if ".enc" in name:
        return "atlas grids"
    if ".atlases." in name:
        return "atlas MLP"
    if ".deformations." in name:
        return "deformation"
    if name.startswith("blur"):
        return "blur generator"
    return "tone mapper and exposures"


def kept_for_backward(r) -> tuple[float, float]:
    """``(fixed, per_sample)``: the bytes autograd keeps for the backward pass of one training step
    of the model the resolved settings ``r`` build, ``fixed + per_sample * batch``, measured: the
    model's loss (every term it computes at the start of training, masks and flow matches
    included) evaluated on the CPU for a stand-in clip (``PROBE_FRAMES`` frames of ``PROBE_HW``
    px: the tensors a sample keeps follow the model's structure, not the clip's size) at the two
    batch sizes of ``PROBE``, its saved tensors counted once each (parameters not: they are
    :data:`PARAM_BYTES`'s). Random weights and samples; no gradient is computed. Measured once per
    resolved settings in a process (a run estimates before its work and again after the analysis)."""
    import json

    key = json.dumps(r.to_dict(), sort_keys=True, default=str)
    if key not in _KEPT:
        _KEPT[key] = _measure_kept(r)
    return _KEPT[key]


_KEPT: dict[str, tuple[float, float]] = {}  # kept_for_backward's measures, by resolved settings


def _measure_kept(r) -> tuple[float, float]:
    import torch

    from layercam.engine.checkpoint import build_model
    from layercam.engine.sampler import PROBES

    T = PROBE_FRAMES
    m = r.settings.model
    meta = identity_meta(r, T, (PROBE_HW, PROBE_HW))
    with torch.random.fork_rng():
        torch.manual_seed(0)
        model = build_model(r, meta)
        if model.scene.alpha is not None:
            model.loss_weights.alpha_mask = 1.0
        if r.settings.train.bootstrap_steps > 0:
            model.loss_weights.bootstrap = 1.0
        params = {p.untyped_storage().data_ptr() for p in model.parameters()}
        kept = []
        for n in PROBE:
            t = torch.randint(0, T, (n,))
            batch = {"t": t, "xy": torch.rand(n, 2) * 2 - 1, "rgb": torch.rand(n, 3),
                     "mask": (torch.rand(n) < 0.5).float(),
                     "probe": torch.rand(PROBES, 3)}
            if m.flow_loss:
                batch.update(t_match=(t + 1).clamp(max=T - 1), xy_match=torch.rand(n, 2) * 2 - 1,
                             match_ok=torch.ones(n, dtype=torch.bool))
            seen: dict[int, int] = {}

            def pack(x, seen=seen):
                st = x.untyped_storage()
                if st.data_ptr() not in params:
                    seen[st.data_ptr()] = st.nbytes()
                return x

            with torch.autograd.graph.saved_tensors_hooks(pack, lambda x: x):
                model.loss_dict(batch)
            kept.append(float(sum(seen.values())))
    per = max((kept[1] - kept[0]) / (PROBE[1] - PROBE[0]), 0.0)
    return max(kept[0] - per * PROBE[0], 0.0), per


def floats_per_sample(cfg) -> dict:
    """Floats one training sample carries through each part's networks (their inputs and each
    layer's output), by part (as :data:`layercam.engine.estimate.SETTINGS` names them), for the
    resolved settings ``cfg``:
    which part a batch's activations are most for (:func:`kept_for_backward` measures how much)."""
    from layercam.scene import fields as f

    s, L = cfg.scene, int(cfg.model.layers)
    mlp = lambda i, w, d, o=1: i + w * (d + 1) * 2 + o  # noqa: E731 - pre- and post-activation per hidden layer
    n = int(cfg.blur.n) if cfg.model.blur == "on" else 1
    k = n * n * (2 if cfg.model.flow_loss else 1)  # each sample's n x n PSF taps, and its match for the flow loss
    out = {"deformation": k * L * mlp(3 * (1 + 2 * f.DEFORM_PE_FREQS), s.deform_width, s.deform_depth, 2),
           "atlas grids": k * L
           * (s.grid_levels * f.GRID_FEATURES * 4 if s.encoding == "grid"
              else 2 * (1 + 2 * f.ATLAS_PE_FREQS)),
           "atlas MLP": k * L * mlp(0, s.atlas_width, s.atlas_depth, 3),
           "tone mapper and exposures": k * 3 * mlp(1, cfg.tone.width, cfg.tone.depth)}
    if L > 1:
        out["alpha grid"] = k * (f.ALPHA_GRID_LEVELS * f.ALPHA_GRID_FEATURES * 8 if s.alpha_encoding == "grid" else 0)
        out["alpha MLP"] = k * mlp(3 * (1 + 2 * f.ALPHA_PE_FREQS), f.ALPHA_WIDTH, f.ALPHA_DEPTH)
    if n > 1:
        out["blur generator"] = (2 if cfg.model.flow_loss else 1) * 2 * mlp(16, 64, 4, n * n)
    return out
