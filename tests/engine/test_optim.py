"""layercam.engine.optim.Adam: torch's Adam for dense gradients, lazy rows for sparse ones."""

from __future__ import annotations

import copy

import pytest
import torch

from layercam.engine.optim import Adam, coalesce_rows


def _pair(sparse_rows: int = 6, seed: int = 0):
    torch.manual_seed(seed)
    a = torch.nn.Embedding(sparse_rows, 3, sparse=True)
    b = torch.nn.Embedding(sparse_rows, 3)
    b.weight.data.copy_(a.weight.data)
    kw = {"lr": 0.05, "betas": (0.9, 0.99), "eps": 1e-15}
    return a, b, Adam(a.parameters(), **kw), torch.optim.Adam(b.parameters(), **kw)


def test_every_row_touched_is_dense_adam():
    a, b, oa, ob = _pair()
    for _ in range(25):
        idx, tgt = torch.tensor([0, 1, 2, 3, 4, 5, 2, 2]), torch.randn(8, 3)
        for m, o in ((a, oa), (b, ob)):
            o.zero_grad()
            ((m(idx) - tgt) ** 2).sum().backward()
            o.step()
    assert torch.allclose(a.weight, b.weight, atol=1e-6)
    assert torch.allclose(oa.state[a.weight]["exp_avg_sq"], ob.state[b.weight]["exp_avg_sq"], atol=1e-7)


def test_rows_not_named_are_not_touched_until_named_or_flushed():
    a, _, oa, _ = _pair()
    for step in range(10):
        oa.zero_grad()
        a(torch.tensor([0, 1, 2])).sum().backward()
        oa.step()
    before = a.weight.detach().clone(), oa.state[a.weight]["exp_avg"].clone()
    oa.zero_grad()
    a(torch.tensor([0])).sum().backward()
    oa.step()
    assert torch.equal(a.weight[1:], before[0][1:]) and torch.equal(oa.state[a.weight]["exp_avg"][1:], before[1][1:])
    assert not torch.equal(a.weight[0], before[0][0])


def test_rows_touched_now_and_then_follow_dense_adam_once_flushed():
    """Dense Adam keeps moving a row after its last gradient; the catch-up does the same moves
    when the row is next touched (or flushed). Plain lazy Adam (coast=False) does not."""
    torch.manual_seed(0)
    a, b, oa, ob = _pair(sparse_rows=50)
    c = torch.nn.Embedding(50, 3, sparse=True)
    c.weight.data.copy_(a.weight.data)
    oc = Adam(c.parameters(), coast=False, lr=0.05, betas=(0.9, 0.99), eps=1e-15)
    for step in range(700):
        idx = torch.arange(50) if step < 500 else torch.randperm(50)[:5]  # (bias corrections ~1 by then)
        g = torch.randn(len(idx), 3) + 0.5  # gradients that do not depend on the weights
        for m, o in ((a, oa), (b, ob), (c, oc)):
            o.zero_grad()
            (m(idx) * g).sum().backward()
            o.step()
    oa.flush()
    assert (a.weight - b.weight).abs().max() < 1e-3
    assert (c.weight - b.weight).abs().max() > 0.1


def test_dense_and_sparse_parameters_in_one_optimiser_and_its_state_round_trip():
    torch.manual_seed(0)
    emb, lin = torch.nn.Embedding(10, 2, sparse=True), torch.nn.Linear(2, 1)
    opt = Adam([{"params": lin.parameters(), "lr": 1e-2}, {"params": emb.parameters(), "lr": 1e-1}], betas=(0.9, 0.99))

    def step(o):
        o.zero_grad()
        lin(emb(torch.tensor([1, 3, 3]))).pow(2).sum().backward()
        o.step()

    for _ in range(3):
        step(opt)
    saved = copy.deepcopy({"opt": opt.state_dict(), "emb": emb.state_dict(), "lin": lin.state_dict()})
    step(opt)
    after = emb.weight.detach().clone(), lin.weight.detach().clone()
    emb.load_state_dict(saved["emb"])
    lin.load_state_dict(saved["lin"])
    opt2 = Adam([{"params": lin.parameters(), "lr": 1e-2}, {"params": emb.parameters(), "lr": 1e-1}], betas=(0.9, 0.99))
    opt2.load_state_dict(saved["opt"])
    assert opt2.state[emb.weight]["last"].dtype == torch.int32  # a row's step stays an integer
                                                                # (torch casts state to the
                                                                # parameter's dtype)
    step(opt2)
    assert torch.equal(emb.weight, after[0]) and torch.equal(lin.weight, after[1])
    assert emb.weight.grad.is_sparse and lin.weight.grad.layout == torch.strided  # gradients are left in place


def test_coalesce_without_sorting_matches_unique():
    torch.manual_seed(0)
    idx = torch.randint(0, 40, (500,))
    grad = torch.sparse_coo_tensor(idx[None], torch.randn(500, 3), (40, 3))
    rows, vals = coalesce_rows(grad, torch.empty(40, dtype=torch.long))
    assert len(set(rows.tolist())) == len(rows) == len(torch.unique(idx))
    dense = torch.zeros(40, 3)
    dense[rows] = vals
    assert torch.allclose(dense, grad.to_dense(), atol=1e-5)


def test_sparse_step_refuses_what_it_does_not_implement():
    emb = torch.nn.Embedding(4, 2, sparse=True)
    opt = Adam(emb.parameters(), weight_decay=0.1)
    emb(torch.tensor([0])).sum().backward()
    with pytest.raises(ValueError, match="sparse gradients"):
        opt.step()


@pytest.mark.parametrize("device",
                         ["cpu",
                          pytest.param("cuda",
                                       marks=pytest.mark.skipif(not torch.cuda.is_available(),
    reason="no CUDA device"))])
def test_lazy_rows_on_a_device(device):
    """The moments and the scratch live where the parameter does."""
    emb = torch.nn.Embedding(8, 2, sparse=True).to(device)
    opt = Adam(emb.parameters(), lr=0.1)
    emb(torch.tensor([1, 1, 5], device=device)).sum().backward()
    opt.step()
    st = opt.state[emb.weight]
    assert st["exp_avg"].device == emb.weight.device == opt._scratch[emb.weight]["stamp"].device


def test_power_table_matches_the_closed_form_and_grows():
    """The catch-up gathers b1^k, b2^k and the coast sum_{j<=k} q^j from a table instead of raising
    to tensor powers; the table holds the closed form and grows with training."""
    emb = torch.nn.Embedding(4, 2, sparse=True)
    opt = Adam(emb.parameters(), lr=0.1, betas=(0.9, 0.99))
    group = opt.param_groups[0]
    small = opt._powers(group, 10, torch.device("cpu"))
    big = opt._powers(group, 5000, torch.device("cpu"))
    assert small.shape[0] > 10 and big.shape[0] > 5000 and torch.equal(big[: small.shape[0]], small)
    q = 0.9 / 0.99**0.5
    for k in (0, 1, 7, 300, 4999):
        want = torch.tensor([0.9**k, 0.99**k, sum(q**j for j in range(1, k + 1))])
        assert torch.allclose(big[k].double(), want.double(), rtol=1e-5, atol=1e-30)
