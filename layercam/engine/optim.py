"""Adam whose cost on a parameter with a sparse (row) gradient grows with the rows a step names,
not with the parameter: the atlas grids' fine levels (``scene/encodings.py``), of which a step
touches a few thousand cells.

:class:`Adam` is ``torch.optim.Adam`` for every parameter with a dense gradient (its fused kernel,
``fused=True``, unless ``foreach`` is given: on the CPU the per-tensor loop was most of a step's
optimiser cost, chiefly alpha's dense ``(x, y, t)`` grid). For a sparse one
it reads and writes only the rows named, and keeps per row the step it was last brought up to
date (``state["last"]``). Dense Adam keeps moving a row after its last gradient: with zero
gradients its moments decay (``m b1^j``, ``v b2^j``) and it coasts ``lr m / sqrt(v) * q^j``,
``q = b1 / sqrt(b2)``, for some tens of steps (``sum q^j`` ~ 10 with betas 0.9, 0.99: ten times
the step a lone gradient gives). Left out (plain lazy Adam, TensorFlow's ``LazyAdam``, ``coast =
False``), fine cells touched only a few times in training learn too little
(docs/measurements.md). So when a row is touched again, the steps it missed are
applied first in closed form (the geometric sum, at the current learning rate and bias
correction) and its moments decayed by them; :meth:`Adam.flush` brings every row up to date (the
trainer calls it when training ends). With every row touched every step this is dense Adam
exactly; otherwise it differs from it only by the learning rate and bias correction changing
during the missed steps. The state keeps Adam's keys (``step``, ``exp_avg``, ``exp_avg_sq``)
plus ``last``. Unlike ``torch.optim.SparseAdam`` (lazy), which adds its sparse updates into the
dense moments, a step here reads and writes only the rows named: the gradient's repeated rows are
summed without sorting (:func:`coalesce_rows`), the catch-up's factors gathered from a table
(:meth:`Adam._powers`), and each row of the parameter written once (docs/measurements.md has the
timings).
"""

from __future__ import annotations

import torch


def coalesce_rows(grad: torch.Tensor, stamp: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """A sparse row gradient (``sparse_dim = 1``, possibly with repeated rows) -> its distinct rows
    ``(K,)`` (in no particular order) and their summed values ``(K, ...)``.

    ``stamp``: a scratch ``(rows,)`` long tensor; with it the rows are found in ``O(nnz)`` without
    sorting (each entry writes its position into ``stamp`` at its row; the entries that find their
    own position there represent their row), which on one CPU core is 3x faster than ``unique``."""
    idx, vals = grad._indices()[0], grad._values()
    if grad.is_coalesced():
        return idx, vals
    if stamp is None:
        rows, inv = torch.unique(idx, return_inverse=True)
    else:
        pos = torch.arange(idx.shape[0], device=idx.device)
        stamp.scatter_(0, idx, pos)
        rep = stamp.index_select(0, idx)  # the representative entry of each entry's row
        first = rep == pos
        slot = torch.cumsum(first, 0) - 1
        rows, inv = idx[first], slot.index_select(0, rep)
    if vals.dim() == 2:  # summed along dim 1 of the transposed values: along dim 0 the CPU adds row by row (3x slower)
        return rows, vals.new_zeros((vals.shape[1], rows.shape[0])).index_add_(1, inv, vals.t()).t()
    return rows, vals.new_zeros((rows.shape[0],) + vals.shape[1:]).index_add_(0, inv, vals)


class Adam(torch.optim.Adam):
    """``torch.optim.Adam`` plus row-wise updates for parameters whose gradient is sparse (see the
    module's docstring); ``coast=False`` is plain lazy Adam."""

    def __init__(self, params, coast: bool = True, **kw):
        if "foreach" not in kw:  # the dense parameters in one fused kernel (CPU and CUDA alike)
            kw.setdefault("fused", True)
        super().__init__(params, **kw)
        self.coast = coast
        self._scratch: dict = {}

    @torch.no_grad()
    def step(self, closure=None):
        loss = None
        if closure is not None:
            with torch.enable_grad():
                loss = closure()
        held = []
        for group in self.param_groups:
            for p in group["params"]:
                if p.grad is not None and p.grad.is_sparse:
                    self._rows_step(p, p.grad, group)
                    held.append((p, p.grad))
                    p.grad = None  # the dense step below skips it
        super().step()
        for p, g in held:
            p.grad = g
        return loss

    def load_state_dict(self, state_dict: dict) -> None:
        """``torch.optim.Optimizer.load_state_dict``, with each row's ``last`` step kept an integer
        (the base class casts every tensor of a floating parameter's state to its dtype)."""
        last = {i: s["last"] for i, s in state_dict["state"].items() if "last" in s}
        super().load_state_dict(state_dict)
        params = [p for g in self.param_groups for p in g["params"]]
        for i, v in last.items():
            self.state[params[i]]["last"] = v.to(device=params[i].device, dtype=torch.int32)

    @torch.no_grad()
    def flush(self) -> None:
        """Brings every row of the sparse parameters up to the current step (the coasting dense
        Adam would have done since each row's last gradient). O(parameter size): call it once,
        when training ends, not per step."""
        for group in self.param_groups:
            for p in group["params"]:
                st = self.state.get(p, {})
                if "last" in st:
                    rows = torch.arange(p.shape[0], device=p.device)
                    self._catch_up(p, st, group, rows, int(st["step"]), write=True)

    def _powers(self, group: dict, upto: int, device) -> torch.Tensor:
        """``(upto + 1, 3)`` float32 on ``device``: row ``j`` holds ``b1^j``, ``b2^j`` and the coast
        ``sum_{i=1..j} q^i`` (``q = b1 / sqrt(b2)``), computed in float64 once and grown as
        training goes on, so that a step gathers its rows' factors instead of raising to tensor
        powers (three ``pow`` over the rows were a third of a sparse step)."""
        b1, b2 = group["betas"]
        key = ("powers", device, b1, b2)
        tab = self._scratch.get(key)
        if tab is None or tab.shape[0] <= upto:
            j = torch.arange(max(2 * upto, 1024) + 1, dtype=torch.float64)
            q = b1 / b2**0.5
            tab = torch.stack([b1**j, b2**j, q * (1 - q**j) / (1 - q)], 1).to(device=device, dtype=torch.float32)
            self._scratch[key] = tab
        return tab

    def _catch_up(self, p: torch.Tensor, st: dict, group: dict, rows: torch.Tensor, upto: int,
                  write: bool = False) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """Rows ``rows`` brought to step ``upto``: their moments decayed over the steps since
        ``st["last"]``, and the coasting those steps did (at the current learning rate and step
        ``upto``'s bias correction). Returns the moments ``(m, v)`` and the coasting, a change to
        add to the rows (None when none missed a step); ``write`` stores the moments and ``last``
        and applies the change."""
        b1, b2 = group["betas"]
        m = st["exp_avg"].index_select(0, rows)
        v = st["exp_avg_sq"].index_select(0, rows)
        k = (upto - st["last"].index_select(0, rows).long()).clamp_(min=0)
        change = None
        if self.coast and upto > 0 and bool((k > 0).any()):
            f = self._powers(group, upto, m.device).index_select(0, k).to(m.dtype)
            bc1, bc2 = 1 - b1**upto, 1 - b2**upto
            denom = (v / bc2).sqrt_().add_(group["eps"])
            change = (m / denom).mul_(f[:, 2:3] * (-float(group["lr"]) / bc1))
            m.mul_(f[:, 0:1])
            v.mul_(f[:, 1:2])
            if write:
                p.index_add_(0, rows, change)
                st["exp_avg"].index_copy_(0, rows, m)
                st["exp_avg_sq"].index_copy_(0, rows, v)
        if write:
            st["last"].index_fill_(0, rows, upto)
        return m, v, change

    def _rows_step(self, p: torch.Tensor, grad: torch.Tensor, group: dict) -> None:
        if group["weight_decay"] or group["amsgrad"] or group["maximize"]:
            raise ValueError("layercam.engine.optim.Adam: sparse gradients support plain Adam only "
                             "(no weight decay, amsgrad, maximize)")
        if grad.sparse_dim() != 1:
            raise ValueError("layercam.engine.optim.Adam: a sparse gradient must name rows "
                             f"(sparse_dim 1), got {grad.sparse_dim()}")
        state = self.state[p]
        if not state:
            state["step"] = torch.tensor(0.0, dtype=torch.float32)
            state["exp_avg"] = torch.zeros_like(p, memory_format=torch.preserve_format)
            state["exp_avg_sq"] = torch.zeros_like(p, memory_format=torch.preserve_format)
        if "last" not in state:
            state["last"] = torch.full((p.shape[0],), int(state["step"]), dtype=torch.int32, device=p.device)
        if "stamp" not in self._scratch.get(p, {}):  # not state: a scratch, not saved with checkpoints
            self._scratch[p] = {"stamp": torch.empty(p.shape[0], dtype=torch.long, device=p.device)}
        rows, g = coalesce_rows(grad, self._scratch[p]["stamp"])
        if rows.numel() == 0:
            return
        state["step"] += 1
        step = float(state["step"])
        b1, b2 = group["betas"]
        m, v, change = self._catch_up(p, state, group, rows, int(step) - 1)
        m.lerp_(g, 1 - b1)
        v.mul_(b2).addcmul_(g, g, value=1 - b2)
        state["exp_avg"].index_copy_(0, rows, m)
        state["exp_avg_sq"].index_copy_(0, rows, v)
        state["last"].index_fill_(0, rows, int(step))
        bc1, bc2 = 1 - b1**step, 1 - b2**step
        denom = (v / bc2).sqrt_().add_(group["eps"])
        upd = m.div_(denom).mul_(-float(group["lr"]) / bc1)  # (index_add_'s alpha is 20x slower on the CPU)
        if change is not None:  # the coasting and the step in one write
            upd.add_(change)
        p.index_put_((rows,), p.index_select(0, rows).add_(upd))  # rows are distinct: no accumulating scatter
