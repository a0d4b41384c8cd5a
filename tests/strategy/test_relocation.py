"""Relocation policies: count kept, moments reset, and what each policy does to o and s."""


import numpy as np
import pytest
import torch
from torch import nn

from ftgspp.config import StrategyConfig
from ftgspp.strategy import Relocator
from ftgspp.strategy.policies import choose_relocation, mcmc_opacity_scale


def make_params(n=50, n_dead=10, seed=0):
    g = torch.Generator().manual_seed(seed)
    logits = torch.randn(n, generator=g)
    logits[:n_dead] = -8.0  # sigmoid(-8) = 3.4e-4 < 5e-3: dead
    params = nn.ParameterDict({
        "means": nn.Parameter(torch.randn(n, 3, generator=g)),
        "scales": nn.Parameter(torch.randn(n, 3, generator=g) - 2),
        "opacities": nn.Parameter(logits),
        "velocities": nn.Parameter(torch.randn(n, 3, generator=g)),
    })
    opts = {k: torch.optim.Adam([p], lr=1e-2) for k, p in params.items()}
    loss = sum((p**2).sum() for p in params.values())
    loss.backward()
    for o in opts.values():
        o.step()
    return params, opts


@pytest.mark.parametrize("policy", ["mcmc", "exact_copy", "partial_copy"])
def test_policy_semantics(policy):
    params, opts = make_params()
    before = {k: v.detach().clone() for k, v in params.items()}
    reloc = Relocator(StrategyConfig(relocation=policy))
    state = reloc.initialize_state(50)
    gen = torch.Generator().manual_seed(1)
    dead, sources = choose_relocation(torch.sigmoid(before["opacities"]), state["grad2d"], 5e-3,
                                      torch.Generator().manual_seed(1))
    moved = reloc.step(params, opts, state, gen)
    assert moved == 10 and torch.equal(dead, torch.arange(10))
    assert all(v.shape[0] == 50 for v in params.values())  # count kept
    # positions and velocities always come from the sources
    torch.testing.assert_close(params["means"][dead], before["means"][sources])
    torch.testing.assert_close(params["velocities"][dead], before["velocities"][sources])
    if policy == "exact_copy":
        torch.testing.assert_close(params["opacities"][dead], before["opacities"][sources])
        torch.testing.assert_close(params["scales"][dead], before["scales"][sources])
    elif policy == "partial_copy":
        torch.testing.assert_close(params["opacities"][dead], before["opacities"][dead])
        torch.testing.assert_close(params["scales"][dead], before["scales"][dead])
    else:  # mcmc: copies and sources share the reduced opacity
        o_src = torch.sigmoid(before["opacities"][sources])
        o_new = torch.sigmoid(params["opacities"][dead])
        assert torch.all(o_new <= o_src + 1e-6)
        torch.testing.assert_close(params["opacities"][dead], params["opacities"][sources])
    # moments of moved Gaussians (destinations and sources) are zero, others untouched
    moved_idx = torch.cat([dead, sources]).unique()
    for name, opt in opts.items():
        st = opt.state[params[name]]
        assert torch.all(st["exp_avg"][moved_idx] == 0)
        assert torch.all(st["exp_avg_sq"][moved_idx] == 0)
        others = torch.ones(50, dtype=torch.bool)
        others[moved_idx] = False
        assert torch.all(st["exp_avg_sq"][others] > 0)


def test_sources_follow_opacity_and_gradient_score():
    n = 1000
    opacity = torch.full((n,), 0.5)
    opacity[:500] = 1e-4  # dead
    grad = torch.zeros(n)
    grad[-1] = 1.0  # one alive Gaussian has all the gradient: p = 1/500/2 + 1/2
    _, src = choose_relocation(opacity, grad, 5e-3, torch.Generator().manual_seed(0))
    share = (src == n - 1).float().mean().item()
    assert share == pytest.approx(0.5 + 0.5 / 500, abs=0.07)
    assert torch.all(src >= 500)


def test_mcmc_rule_preserves_composited_opacity_and_mass():
    """n copies composite to the original opacity; the 1D alpha mass is preserved (quadrature)."""
    o = torch.tensor([0.2, 0.6, 0.9], dtype=torch.float64)
    s = torch.ones(3, 3, dtype=torch.float64)
    for n in [2, 3, 7]:
        o_new, s_new = mcmc_opacity_scale(o, s, torch.full((3,), n), 1e-9)
        torch.testing.assert_close(1 - (1 - o_new) ** n, o)
        x = np.linspace(-12, 12, 20001)
        for i in range(3):
            sn = s_new[i, 0].item()
            stacked = 1 - (1 - o_new[i].item() * np.exp(-0.5 * (x / sn) ** 2)) ** n
            original = o[i].item() * np.exp(-0.5 * x**2)
            assert np.trapezoid(stacked, x) == pytest.approx(np.trapezoid(original, x), rel=1e-6)


def test_schedule():
    r = Relocator(StrategyConfig(refine_every=100, refine_start_iter=500, refine_stop_iter=25_000))
    assert not r.due(500) and r.due(600) and not r.due(650) and not r.due(25_000) and r.due(24_900)
    with pytest.raises(Exception, match="strategy.relocation"):
        Relocator(StrategyConfig(relocation="teleport"))
