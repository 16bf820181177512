"""Blur generator (paper Sec. 3.2): a learned, per-pixel, per-frame PSF applied to irradiance.

For a pixel ``p_c`` of frame ``i`` the camera records the irradiance blurred by a point spread
function, modelled as ``K = n * n`` samples of the sharp scene blended with weights:

    P' = P + dP,   dP = O(p_c, i),   W = softmax(W(p_c, i)),   r' = sum_k w_k * r(P'_k)

``P`` is the regular ``n x n`` patch of pixel offsets around ``p_c`` (:func:`patch_offsets_base`),
``O`` the offset network (``max_offset * tanh``, so each offset component is bounded by ``s``;
``s = 0`` keeps the fixed patch) and ``W`` the weight network (softmax). The blend runs in the
linear irradiance domain but is computed in log space (:func:`apply_patch_blur`), so that
``log2 r`` anywhere in ``[-40, 40]`` stays finite.

As in kornia, building the kernel (:meth:`BlurGenerator.kernels`) is kept apart from applying it
(:func:`apply_patch_blur`); :func:`sample_positions` turns pixel displacements into the scene's
normalised coordinates (``x`` spans ``W`` pixels over ``[-1, 1]``, ``y`` spans ``H``).

Example:
    >>> import torch
    >>> class Flat(torch.nn.Module):
    ...     def forward(self, xy, t):
    ...         return {"log2_r": xy.new_zeros(xy.shape[0], 3)}
    >>> blur = BlurGenerator(3, 5.0, n_frames=4, frame_hw=(16, 16), width=16, depth=2)
    >>> xy, t = torch.zeros(8, 2), torch.zeros(8, dtype=torch.long)
    >>> blur(Flat(), xy, t).shape
    torch.Size([8, 3])
"""

from __future__ import annotations

import math

import torch
from torch import nn

from layercam.scene.encodings import PositionalEncoding, gather_rows
from layercam.scene.mlp import MLP

__all__ = ["patch_offsets_base", "sample_positions", "apply_patch_blur", "BlurGenerator", "psf_summary"]

_LN2 = math.log(2.0)
LOGIT_BOUND = 1e4  # weight logits are clamped to +-this before the softmax
_TINY = 1e-30  # floor on weights before their log (gradients stay finite where a weight is 0)
# how the model builds and trains it (layercam.engine.model)
INIT_CENTRE_WEIGHT = 0.2  # the PSFs start blurry: a near-sharp start (0.9) lets the scene absorb the blur
WARMUP = 0.2  # share of training with the PSFs held at their start while the scene takes shape: trained from
              # step 0, every PSF collapsed to a delta within 25 steps


def patch_offsets_base(n: int, device=None, dtype=torch.float32) -> torch.Tensor:
    """Regular ``n x n`` grid of pixel offsets centred at 0 with 1 px spacing: ``(n*n, 2)``, x-y order.

    Row-major (``y`` outer, ``x`` inner), so index ``n*n // 2`` is the centre ``(0, 0)`` for odd ``n``.

    >>> patch_offsets_base(3)[4]
    tensor([0., 0.])
    """
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"patch size n must be an integer >= 1, got {n!r}")
    r = torch.arange(n, device=device, dtype=dtype) - (n - 1) / 2.0
    ys, xs = torch.meshgrid(r, r, indexing="ij")
    return torch.stack([xs.flatten(), ys.flatten()], dim=1)


def sample_positions(xy: torch.Tensor, offsets_px: torch.Tensor, frame_hw: tuple[int, int]) -> torch.Tensor:
    """Patch centres ``xy (N, 2)`` (normalised) + displacements ``offsets_px (N, K, 2)`` (pixels).

    Returns ``(N, K, 2)`` normalised positions: ``dx_norm = 2 * dx_px / W``, ``dy_norm = 2 * dy_px / H``.
    """
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ValueError(f"sample_positions expects xy (N, 2), got {tuple(xy.shape)}")
    if offsets_px.ndim != 3 or offsets_px.shape[0] != xy.shape[0] or offsets_px.shape[2] != 2:
        raise ValueError(f"sample_positions expects offsets (N, K, 2) with N={xy.shape[0]}, got "
                         f"{tuple(offsets_px.shape)}")
    h, w = frame_hw
    scale = offsets_px.new_tensor([2.0 / w, 2.0 / h])
    return xy[:, None, :].to(offsets_px.dtype) + offsets_px * scale


def _apply_log_weights(log2_r_patch: torch.Tensor, log_w: torch.Tensor) -> torch.Tensor:
    """``log2 sum_k exp(log_w_k) 2^{log2_r_k}`` over ``K``: ``(N, K, C), (N, K) -> (N, C)`` in float32."""
    z = log2_r_patch.float() * _LN2 + log_w.float()[:, :, None]
    return torch.logsumexp(z, dim=1) / _LN2


def apply_patch_blur(log2_r_patch: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """Blend a patch of log2 irradiances with non-negative weights, in the linear domain.

    ``r' = sum_k w_k * 2^{log2_r_k}``, returned as ``log2 r'``; computed as a logsumexp of
    ``log2_r_k * ln 2 + ln w_k`` so that ``log2 r`` of +-40 (or more) stays finite. Weights of 0
    drop their sample (floored at 1e-30 inside the log, so gradients stay finite).

    Args:
        log2_r_patch: ``(N, K, C)`` log2 irradiance of the ``K`` samples (C is 3 for RGB).
        weights: ``(N, K)`` non-negative blend weights (a PSF sums to 1, not required here).

    Returns:
        ``(N, C)`` log2 of the blended irradiance, in the dtype of ``log2_r_patch``.

    >>> lr = torch.log2(torch.tensor([[[1.0], [3.0]]]))
    >>> round(torch.exp2(apply_patch_blur(lr, torch.tensor([[0.5, 0.5]]))).item(), 4)
    2.0
    """
    if log2_r_patch.ndim != 3:
        raise ValueError(f"apply_patch_blur expects log2_r_patch (N, K, C), got {tuple(log2_r_patch.shape)}")
    if weights.shape != log2_r_patch.shape[:2]:
        raise ValueError("apply_patch_blur expects weights (N, K) = "
                         f"{tuple(log2_r_patch.shape[:2])}, got {tuple(weights.shape)}")
    log_w = torch.log(weights.float().clamp_min(_TINY))
    return _apply_log_weights(log2_r_patch, log_w).to(log2_r_patch.dtype)


def _first_rows(v, n: int):
    """The first ``n`` rows of a scene output's entry (a tensor, a list of them, or None)."""
    if v is None:
        return None
    return [x[:n] for x in v] if isinstance(v, list) else v[:n]


class BlurGenerator(nn.Module):
    """The paper's blur generator: offset net ``O`` and weight net ``W`` on ``(x, y, frame)``.

    Both nets take ``PE(x, y)`` (``pe_freqs`` frequencies), a learned per-frame embedding
    (``embed_dim``; the paper's image index: each image gets its own blur pattern) and, when
    ``use_depth``, a per-pixel depth ``(N, 1)``; each is an MLP of ``depth`` hidden layers of
    ``width`` (paper: 4 x 64).

    * ``O`` outputs ``K * 2`` pixel offsets ``max_offset * tanh(.)``; its last layer is zero so the
      start is the plain ``n x n`` patch. With ``max_offset == 0`` there is no ``O`` (fixed patch).
    * ``W`` outputs ``K`` logits (clamped to +-1e4) -> softmax; its last layer starts at zero with a
      bias on the centre logit so the centre sample holds ``init_centre_weight`` (near-sharp start).
    * ``zero_mean_offsets``: the ``K`` learned offsets of a patch have zero mean, so they shape and
      spread the patch but cannot translate it: the offsets cannot act as a per-pixel warp (the
      scene's deformation is one already), which otherwise lets a trained model shift the whole
      PSF (the sharp render then lands pixels away from the input) or store each frame apart instead
      of blurring. Each offset then stays within ``2 * max_offset``.
    * ``centre_exact``: the displacements are moved by minus their *weighted* mean, so each PSF's
      centre of mass is its pixel (the weights cannot shift it either). Right for defocus, where the
      scene does not move; a delta on any sample is then an identity PSF, which trained from step
      0 on a grid finer than the pixels collapsed there (the model's warm-up and grid cap avoid it).

    Args:
        n: patch size (odd), ``K = n * n`` samples per pixel.
        max_offset: ``s``, bound on each offset component in pixels (0 = fixed patch).
        n_frames: number of frames (images) with their own embedding.
        frame_hw: ``(H, W)`` of the frames in pixels (for pixel -> normalised units).
        width, depth: hidden width and number of hidden layers of both nets.
    """

    def __init__(
        self,
        n: int,
        max_offset: float,
        n_frames: int,
        frame_hw: tuple[int, int],
        width: int = 64,
        depth: int = 4,
        *,
        embed_dim: int = 8,
        pe_freqs: int = 4,
        use_depth: bool = False,
        init_centre_weight: float = 0.9,
        zero_mean_offsets: bool = False,
        centre_exact: bool = False,
    ):
        super().__init__()
        if isinstance(n, bool) or not isinstance(n, int) or n < 1 or n % 2 == 0:
            raise ValueError(f"blur patch size n must be an odd integer >= 1, got {n!r}")
        if not math.isfinite(float(max_offset)) or max_offset < 0:
            raise ValueError(f"max_offset must be a finite number >= 0, got {max_offset!r}")
        if n_frames < 1:
            raise ValueError(f"n_frames must be >= 1, got {n_frames}")
        h, w = (int(v) for v in frame_hw)
        if h < 1 or w < 1:
            raise ValueError(f"frame_hw must be (H, W) >= 1, got {frame_hw!r}")
        if not 0.0 < init_centre_weight < 1.0 and not (n == 1 and init_centre_weight == 1.0):
            raise ValueError(f"init_centre_weight must be in (0, 1), got {init_centre_weight}")
        self.n, self.K = n, n * n
        self.max_offset = float(max_offset)
        self.n_frames = int(n_frames)
        self.frame_hw = (h, w)
        self.use_depth = bool(use_depth)
        self.zero_mean_offsets = bool(zero_mean_offsets)
        self.centre_exact = bool(centre_exact)
        self.register_buffer("base", patch_offsets_base(n), persistent=False)
        self.embedding = nn.Parameter(torch.randn(self.n_frames, embed_dim) * 0.5)
        self.pe = PositionalEncoding(2, pe_freqs)
        in_dim = self.pe.out_dim + embed_dim + int(self.use_depth)
        self.offset_net = MLP(in_dim, self.K * 2, width, depth, zero_last=True) if self.max_offset > 0 else None
        self.weight_net = MLP(in_dim, self.K, width, depth, zero_last=True)
        with torch.no_grad():
            if self.K > 1:
                # softmax([b, 0, ..., 0])[centre] = e^b / (e^b + K - 1) = init_centre_weight
                b = math.log(init_centre_weight / (1 - init_centre_weight) * (self.K - 1))
                self.weight_net.last.bias[self.K // 2] = b

    # -- kernel ------------------------------------------------------------------------------
    def frame_embedding(self, t: torch.Tensor | None = None, t_blur: torch.Tensor | None = None) -> torch.Tensor:
        """Per-sample embedding ``(N, embed_dim)``: by long frame index ``t (N,)``, or by a float frame
        coordinate ``t_blur (N,)`` (linear interpolation between neighbouring frames, clamped to range)."""
        if t_blur is None:
            if t is None:
                raise ValueError("frame_embedding needs t or t_blur")
            if t.is_floating_point():
                raise ValueError("t must be an integer frame index; pass float frame coordinates as t_blur")
            return gather_rows(self.embedding, t)  # (a deterministic backward: gather_rows)
        tb = t_blur.float().clamp(0, self.n_frames - 1)
        i0 = tb.floor().long().clamp(0, self.n_frames - 1)
        i1 = (i0 + 1).clamp(max=self.n_frames - 1)
        frac = (tb - i0.float())[:, None]
        return gather_rows(self.embedding, i0) * (1 - frac) + gather_rows(self.embedding, i1) * frac

    def _inputs(self, xy: torch.Tensor, t: torch.Tensor | None, depth: torch.Tensor | None,
                t_blur: torch.Tensor | None) -> torch.Tensor:
        n = xy.shape[0]
        if xy.ndim != 2 or xy.shape[1] != 2:
            raise ValueError(f"BlurGenerator expects xy (N, 2), got {tuple(xy.shape)}")
        if t is not None and t.shape != (n,):
            raise ValueError(f"BlurGenerator expects t (N,) with N={n}, got {tuple(t.shape)}")
        if t_blur is not None and t_blur.shape != (n,):
            raise ValueError(f"BlurGenerator expects t_blur (N,) with N={n}, got {tuple(t_blur.shape)}")
        feats = [self.pe(xy.float()), self.frame_embedding(t, t_blur)]
        if self.use_depth:
            if depth is None or depth.shape != (n, 1):
                got = None if depth is None else tuple(depth.shape)
                raise ValueError("this BlurGenerator was built with use_depth=True: pass depth "
                                 f"(N, 1) with N={n}, got {got}")
            feats.append(depth.float())
        return torch.cat(feats, dim=1)

    def _kernel(self, xy, t, depth=None, t_blur=None, centre: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
        """``(displacements px (N, K, 2), log weights (N, K))``, float32; ``centre``: each PSF's
        weighted centre moved onto its pixel as ``centre_exact`` does, whatever it says."""
        h = self._inputs(xy, t, depth, t_blur)
        disp = self.base.expand(h.shape[0], -1, -1)
        if self.offset_net is not None:
            off = (self.max_offset * torch.tanh(self.offset_net(h).float())).view(-1, self.K, 2)
            if self.zero_mean_offsets:
                off = off - off.mean(1, keepdim=True)
            disp = disp + off
        log_w = torch.log_softmax(self.weight_net(h).float().clamp(-LOGIT_BOUND, LOGIT_BOUND), dim=1)
        if self.centre_exact or centre:  # every PSF's weighted centre on its pixel
            disp = disp - (log_w.exp()[:, :, None] * disp).sum(1, keepdim=True)
        return disp, log_w

    def kernels(self, xy: torch.Tensor, t: torch.Tensor | None = None, *,
                depth: torch.Tensor | None = None,
                t_blur: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """The PSF at ``M`` pixels: ``xy (M, 2)`` normalised, ``t (M,)`` long (or ``t_blur (M,)`` float).

        Returns ``(offsets (M, K, 2), weights (M, K))``: each sample's displacement from the pixel
        centre in pixels (the base patch plus the learned offset, x-y order) and its softmax
        weight (rows sum to 1).
        """
        disp, log_w = self._kernel(xy, t, depth, t_blur)
        return disp, log_w.exp()

    # -- apply -------------------------------------------------------------------------------
    def centre_fixed(self, centre: bool = False) -> bool:
        """Whether each patch's centre sample lies on its pixel (a fixed patch, not moved to its
        weighted centre): the scene's value there is the sharp one, which :meth:`forward` reuses."""
        return self.offset_net is None and not (self.centre_exact or centre)

    def through(self, scene: nn.Module, xy: torch.Tensor, t: torch.Tensor, **kw) -> tuple[dict, torch.Tensor]:
        """The scene's output at pixels ``xy (N, 2)`` of frames ``t (N,)`` and their blurry ``log2 r'
        (N, 3)`` (:meth:`forward`'s). With learned offsets the pixels and their PSFs' samples go
        through the scene in one call: one pass through each field and one gradient per grid a
        training step, not two to add. ``kw`` goes to the scene, the pixels its first rows: an
        entry of at most ``N`` rows (:class:`layercam.scene.layered.LayeredScene`'s ``fg_held``)
        comes back whole."""
        if self.centre_fixed():
            out = scene(xy, t, **kw)
            return out, self(scene, xy, t, out)
        disp, log_w = self._kernel(xy, t)
        pos = sample_positions(xy.float(), disp, self.frame_hw)
        n = xy.shape[0]
        both = scene(torch.cat([xy.to(pos.dtype), pos.reshape(-1, 2)]), torch.cat([t, t.repeat_interleave(self.K)]),
                     **kw)
        out = {key: _first_rows(v, n) for key, v in both.items()}
        return out, _apply_log_weights(both["log2_r"][n:].float().view(n, self.K, -1), log_w)

    def forward(
        self,
        scene: nn.Module,
        xy: torch.Tensor,
        t: torch.Tensor,
        out: dict | None = None,
        *,
        depth: torch.Tensor | None = None,
        t_blur: torch.Tensor | None = None,
        centre: bool = False,
    ) -> torch.Tensor:
        """Blurry ``log2 r' (N, 3)`` at patch centres ``xy (N, 2)`` of frames ``t (N,)``.

        ``scene(xy (M, 2), t (M,))`` must return ``{"log2_r": (M, 3)}``; it is called once on all
        ``N * K`` sample positions. ``out`` (the scene's output at ``xy``) is reused for the centre
        sample when the patch is fixed (``max_offset == 0``). ``t_blur (N,)`` (float) replaces ``t``
        for the blur nets only (focus interpolation); ``depth (N, 1)`` when built ``use_depth``.
        ``centre``: the PSFs' shape without their shift (each weighted centre on its pixel; the
        sharp export's check, :mod:`layercam.pipelines.view`).
        """
        n = xy.shape[0]
        disp, log_w = self._kernel(xy, t, depth, t_blur, centre)
        pos = sample_positions(xy.float(), disp, self.frame_hw)  # (N, K, 2)
        c = self.K // 2
        if self.centre_fixed(centre) and out is not None and self.K > 1:
            keep = torch.arange(self.K, device=xy.device) != c  # centre already rendered in `out`
            others = pos[:, keep].reshape(-1, 2)
            lr = scene(others, t.repeat_interleave(self.K - 1))["log2_r"].float().view(n, self.K - 1, -1)
            centre = out["log2_r"].float()[:, None]
            patch = torch.cat([lr[:, :c], centre, lr[:, c:]], dim=1)
        else:
            patch = scene(pos.reshape(-1, 2), t.repeat_interleave(self.K))["log2_r"].float().view(n, self.K, -1)
        return _apply_log_weights(patch, log_w)

    def extra_repr(self) -> str:
        return (f"n={self.n}, max_offset={self.max_offset:g}, n_frames={self.n_frames}, "
                f"frame_hw={self.frame_hw}, use_depth={self.use_depth}, "
                f"zero_mean_offsets={self.zero_mean_offsets}")


@torch.no_grad()
def psf_summary(blur: "BlurGenerator", hw: tuple[int, int], grid: int = 24) -> dict:
    """Per frame, the learned PSF on a ``grid x grid`` lattice of pixels, averaged: ``spread_px``
    (weighted RMS distance of the samples from their weighted centre: 0 for a sharp frame, about
    ``L / sqrt(12)`` for a straight blur of length ``L``), ``centre_weight`` and ``shift_px`` (the
    length of the PSF's weighted centre). The lattice leaves out a border as wide as the patch can
    reach (``n // 2 + 2 s`` px, at most a quarter of the frame): there samples fall outside the
    frame and nothing constrains the PSF."""
    from layercam.scene.coords import normalise_xy

    h, w = hw
    reach = blur.n // 2 + 2 * blur.max_offset
    my, mx = (int(min(reach, (v - 1) // 4)) for v in (h, w))
    ys = torch.linspace(my, h - 1 - my, min(grid, h - 2 * my)).round()
    xs = torch.linspace(mx, w - 1 - mx, min(grid, w - 2 * mx)).round()
    yy, xx = torch.meshgrid(ys, xs, indexing="ij")
    xy = normalise_xy(xx.flatten(), yy.flatten(), w, h)
    dev = blur.embedding.device
    xy = xy.to(dev)
    rows = {"spread_px": [], "centre_weight": [], "shift_px": []}
    for t in range(blur.n_frames):
        disp, wts = blur.kernels(xy, torch.full((xy.shape[0],), t, dtype=torch.long, device=dev))
        centre = (wts[:, :, None] * disp).sum(1)
        spread = ((wts * ((disp - centre[:, None]) ** 2).sum(-1)).sum(1)).sqrt()
        rows["spread_px"].append(round(float(spread.mean()), 4))
        rows["centre_weight"].append(round(float(wts[:, blur.K // 2].mean()), 4))
        rows["shift_px"].append(round(float(centre.norm(dim=1).mean()), 4))
    return rows
