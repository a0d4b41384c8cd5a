"""``adam_step`` against ``torch.optim.Adam.step``: the same bits, state and state_dict."""

from __future__ import annotations

import copy

import torch
from torch.optim.optimizer import register_optimizer_step_pre_hook

from ftgspp.optim import adam_step, plain_fused_adam


def _twin_optimizers() -> tuple[list[torch.nn.Parameter], torch.optim.Adam, list[torch.nn.Parameter], torch.optim.Adam]:
    gen = torch.Generator().manual_seed(3)
    shapes = [(37, 3), (5000,), (101, 15, 3), (2, 3, 3)]  # tails that are no multiple of a vector
    a = [torch.nn.Parameter(torch.randn(s, generator=gen)) for s in shapes]
    b = [torch.nn.Parameter(p.detach().clone()) for p in a]

    def make(ps: list[torch.nn.Parameter]) -> torch.optim.Adam:
        groups = [{"params": [ps[0]], "lr": 1.6e-4}, {"params": [ps[1], ps[2]], "lr": 5e-3},
                  {"params": [ps[3]], "lr": 1e-3, "betas": (0.8, 0.99)}]
        return torch.optim.Adam(groups, eps=1e-15, fused=True)

    return a, make(a), b, make(b)


def test_adam_step_matches_torch_bit_for_bit() -> None:
    a, opt_a, b, opt_b = _twin_optimizers()
    assert plain_fused_adam(opt_b)
    gen = torch.Generator().manual_seed(4)
    for step in range(6):
        for pa, pb in zip(a, b):
            if pa is a[3] and step < 3:  # a group whose gradients start later (the colour correction)
                pa.grad = pb.grad = None
                continue
            g = torch.randn(pa.shape, generator=gen) * 10.0 ** (step % 3 - 1)
            pa.grad, pb.grad = g.clone(), g.clone()
        for i, group in enumerate(opt_a.param_groups):  # rates that change every step, as the trainer's do
            group["lr"] = opt_b.param_groups[i]["lr"] = 1e-3 * 0.9**step * (i + 1)
        opt_a.step()
        adam_step(opt_b)
        for pa, pb in zip(a, b):
            assert torch.equal(pa.view(torch.int32), pb.view(torch.int32))
        assert len(opt_b.state) == (3 if step < 3 else 4)
    sa, sb = opt_a.state_dict(), opt_b.state_dict()
    assert sa["param_groups"] == sb["param_groups"]
    for k, state in sa["state"].items():
        for name, t in state.items():
            other = sb["state"][k][name]
            assert t.dtype == other.dtype and t.shape == other.shape
            assert torch.equal(t.view(torch.int32), other.view(torch.int32)), (k, name)
    assert float(sb["state"][3]["step"]) == 3.0  # counted only from its first gradient


def test_plain_fused_adam_refuses_what_adam_step_does_not_do() -> None:
    p = torch.nn.Parameter(torch.zeros(3))
    assert not plain_fused_adam(torch.optim.Adam([p]))  # not fused
    assert not plain_fused_adam(torch.optim.Adam([p], fused=True, weight_decay=0.1))
    assert not plain_fused_adam(torch.optim.Adam([p], fused=True, amsgrad=True))
    assert not plain_fused_adam(torch.optim.AdamW([p], fused=True))
    hooked = torch.optim.Adam([p], fused=True)
    hooked.register_step_post_hook(lambda *args: None)
    assert not plain_fused_adam(hooked)
    plain = torch.optim.Adam([p], fused=True)
    assert plain_fused_adam(plain)
    handle = register_optimizer_step_pre_hook(lambda *args: None)  # a global hook
    try:
        assert not plain_fused_adam(plain)
    finally:
        handle.remove()
    plain.step = lambda *args, **kwargs: None  # patched on the instance, as LR schedulers once did
    assert not plain_fused_adam(plain)
    mixed = torch.optim.Adam([p, torch.nn.Parameter(torch.zeros(3, dtype=torch.float64))], fused=True)
    assert not plain_fused_adam(mixed)


def test_adam_step_after_a_checkpoint_matches_torch() -> None:
    """Resume: state loaded from another optimizer's state_dict, then stepped both ways."""
    a, opt_a, b, opt_b = _twin_optimizers()
    gen = torch.Generator().manual_seed(9)
    for p in a:
        p.grad = torch.randn(p.shape, generator=gen)
    opt_a.step()
    for pa, pb in zip(a, b):
        pb.data.copy_(pa.data)
    opt_b.load_state_dict(copy.deepcopy(opt_a.state_dict()))  # as from a checkpoint file
    for _ in range(3):
        for pa, pb in zip(a, b):
            g = torch.randn(pa.shape, generator=gen)
            pa.grad, pb.grad = g.clone(), g.clone()
        opt_a.step()
        adam_step(opt_b)
    for pa, pb in zip(a, b):
        assert torch.equal(pa.view(torch.int32), pb.view(torch.int32))


def test_clear_grads_drops_every_gradient_as_zero_grad_does() -> None:
    from ftgspp.optim import clear_grads

    ps = [torch.nn.Parameter(torch.ones(2)) for _ in range(3)]
    opt = torch.optim.Adam([{"params": ps[:2]}, {"params": ps[2:]}], fused=True)
    for p in ps:
        p.grad = torch.ones(2)
    clear_grads(opt)
    assert all(p.grad is None for p in ps)
