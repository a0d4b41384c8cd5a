"""Relocation policies: count kept, moments reset, and what each policy does to o and s."""


import math

import numpy as np
import pytest
import torch
from scipy import stats
from torch import nn

from ftgspp.config import StrategyConfig
from ftgspp.errors import InputError
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
    opt = torch.optim.Adam([{"params": [p], "name": k} for k, p in params.items()], lr=1e-2)
    loss = sum((p**2).sum() for p in params.values())
    loss.backward()
    opt.step()
    return params, opt


def mcmc_by_hand(o: float, s: float, n: int, min_opacity: float, clamp: str) -> tuple[float, float]:
    """Eq. 9 of 3DGS-MCMC written out in plain Python floats (the independent oracle)."""
    o_new = 1.0 - (1.0 - o) ** (1.0 / n)
    if clamp == "before":
        o_new = min(max(o_new, min_opacity), 1.0 - 1.1920929e-07)
    d = 0.0
    for i in range(1, n + 1):
        for k in range(i):
            d += math.comb(i - 1, k) * (-1) ** k / math.sqrt(k + 1) * o_new ** (k + 1)
    return min(max(o_new, min_opacity), 1.0 - 1.1920929e-07), o / d * s


@pytest.mark.parametrize("reset", ["sources", "moved"])
@pytest.mark.parametrize("policy", ["mcmc", "exact_copy", "partial_copy"])
def test_policy_semantics(policy, reset):
    params, opt = make_params()
    before = {k: v.detach().clone() for k, v in params.items()}
    moments_before = {k: opt.state[p]["exp_avg_sq"].clone() for k, p in params.items()}
    reloc = Relocator(StrategyConfig(relocation=policy, reset_moments=reset))
    state = reloc.initialize_state(50)
    moved = reloc.step(params, opt, state, torch.Generator().manual_seed(1))
    dead = torch.arange(10)  # make_params kills the first ten
    assert moved == 10
    assert all(v.shape[0] == 50 for v in params.values())  # count kept
    # Identify each destination's source by its (unique) position, without the sampler.
    match = (params["means"].detach()[dead, None, :] == before["means"][None, :, :]).all(-1)  # [10, 50]
    assert torch.all(match.sum(1) == 1), "every destination is an exact positional copy of one Gaussian"
    sources = match.float().argmax(1)
    assert torch.all(sources >= 10), "sources are alive Gaussians"
    torch.testing.assert_close(params["velocities"][dead], before["velocities"][sources], rtol=0, atol=0)
    if policy == "exact_copy":
        torch.testing.assert_close(params["opacities"][dead], before["opacities"][sources], rtol=0, atol=0)
        torch.testing.assert_close(params["scales"][dead], before["scales"][sources], rtol=0, atol=0)
    elif policy == "partial_copy":
        torch.testing.assert_close(params["opacities"][dead], before["opacities"][dead], rtol=0, atol=0)
        torch.testing.assert_close(params["scales"][dead], before["scales"][dead], rtol=0, atol=0)
    else:  # mcmc: sources and their copies share the opacity and scale of Eq. 9
        counts = torch.bincount(sources, minlength=50)
        for src in sources.unique().tolist():
            o_src = torch.sigmoid(before["opacities"][src]).item()
            for k in range(3):
                s_src = torch.exp(before["scales"][src, k]).item()
                o_exp, s_exp = mcmc_by_hand(o_src, s_src, int(counts[src]) + 1, 5e-3, "after")
                for idx in [src] + dead[sources == src].tolist():
                    assert torch.sigmoid(params["opacities"][idx]).item() == pytest.approx(o_exp, rel=1e-4)
                    assert torch.exp(params["scales"][idx, k]).item() == pytest.approx(s_exp, rel=1e-4)
        untouched = torch.ones(50, dtype=torch.bool)
        untouched[torch.cat([dead, sources])] = False
        torch.testing.assert_close(params["scales"][untouched], before["scales"][untouched], rtol=0, atol=0)
    # moments of the sources (gsplat's relocate), or of sources and destinations, are zero;
    # all others untouched
    moved_idx = (sources if reset == "sources" else torch.cat([dead, sources])).unique()
    for name, p in params.items():
        st = opt.state[p]
        assert torch.all(st["exp_avg"][moved_idx] == 0)
        assert torch.all(st["exp_avg_sq"][moved_idx] == 0)
        others = torch.ones(50, dtype=torch.bool)
        others[moved_idx] = False
        assert torch.equal(st["exp_avg_sq"][others], moments_before[name][others])
        assert torch.all(st["exp_avg_sq"][others] > 0)


@pytest.mark.parametrize(("clamp", "factor"), [("after", 0.99956), ("before", 0.60106)])
def test_mcmc_clamp_order_against_hand_computed_values(clamp, factor):
    """o = 0.006 split two ways: o_new = 1 - sqrt(0.994) = 0.0030045 is below min_opacity 0.005.
    gsplat 1.5.3 ("after") takes D = 2 o_new - o_new^2/sqrt(2) from the unclamped value:
    s_new/s = 0.006 / 0.0060026 = 0.99956; gsplat >= 1.6 ("before") clamps first:
    0.006 / (0.01 - 0.005^2/sqrt(2)) = 0.60106. Both store the clamped opacity 0.005."""
    o_new, s_new = mcmc_opacity_scale(torch.tensor([0.006], dtype=torch.float64),
                                      torch.ones(1, 3, dtype=torch.float64), torch.tensor([2]), 5e-3, clamp)
    assert s_new[0, 0].item() == pytest.approx(factor, abs=1e-5)
    assert o_new.item() == pytest.approx(0.005)
    assert mcmc_by_hand(0.006, 1.0, 2, 5e-3, clamp)[1] == pytest.approx(factor, abs=1e-5)


def test_relocator_defaults_to_the_papers_clamp_order():
    assert StrategyConfig().mcmc_clamp == "after"
    with pytest.raises(InputError, match="strategy.mcmc_clamp"):
        Relocator(StrategyConfig(mcmc_clamp="sometimes"))


def test_sources_are_drawn_in_proportion_to_opacity_plus_gradient_share():
    """p = o/Σo + g/Σg (normalised) over the alive set, with unequal opacities; chi-square."""
    n_dead, opacity = 30_000, torch.tensor([0.1, 0.3, 0.6])
    all_opacity = torch.cat([torch.full((n_dead,), 1e-4), opacity])
    for grad, expected in ((torch.zeros(3), [0.1, 0.3, 0.6]), (torch.tensor([0.5, 0.5, 0.0]), [0.3, 0.4, 0.3])):
        all_grad = torch.cat([torch.zeros(n_dead), grad])
        dead, src = choose_relocation(all_opacity, all_grad, 5e-3, torch.Generator().manual_seed(0))
        assert torch.equal(dead, torch.arange(n_dead))
        counts = torch.bincount(src - n_dead, minlength=3).numpy()
        assert counts.sum() == n_dead
        assert stats.chisquare(counts, np.array(expected) * n_dead).pvalue > 1e-3
        assert np.abs(counts / n_dead - expected).max() < 0.01


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


def test_statistics_add_the_gradient_norm_of_visible_gaussians_only():
    reloc = Relocator(StrategyConfig())
    state = reloc.initialize_state(6)
    radii = torch.tensor([[2, 3], [0, 3], [1, 0], [4, 4], [0, 0], [1, 1]], dtype=torch.int32)
    nan, inf = float("nan"), float("inf")  # in rows nobody saw: they must not leak into the sums
    grads = [torch.tensor([[3.0, 4.0], [nan, 1.0], [inf, 2.0], [0.0, -2.0], [5.0, 5.0], [-6.0, 8.0]]),
             torch.tensor([[0.0, 1.0], [9.0, 9.0], [9.0, 9.0], [1.5, 2.0], [nan, inf], [0.0, 0.0]])]
    for g in grads:
        reloc.accumulate(state, g, radii)
    visible = [True, False, False, True, False, True]  # both radii > 0
    for i, vis in enumerate(visible):  # by hand: the sum of ||g_i|| over the passes that saw i
        expect = sum(math.hypot(*g[i].tolist()) for g in grads) if vis else 0.0
        assert state["grad2d"][i].item() == pytest.approx(expect, rel=1e-6)
        assert state["count"][i].item() == (2.0 if vis else 0.0)


def test_statistics_kernel_adds_the_same_bits_as_the_tensor_formula(monkeypatch):
    """The cpu path (one Numba pass) against the masked tensor adds it replaced, bit for bit,
    over many passes of random gradients (NaN and inf in rows nobody saw) with some radii zero
    on one axis or both, given as a non-contiguous view."""
    from ftgspp.strategy import relocate

    calls = []
    kernel = relocate._add_visible
    monkeypatch.setattr(relocate, "_add_visible", lambda *a: calls.append(1) or kernel(*a))
    reloc = Relocator(StrategyConfig())
    n = 4099
    state = reloc.initialize_state(n)
    grad2d, count = torch.zeros(n), torch.zeros(n)
    gen = torch.Generator().manual_seed(3)
    for _ in range(20):
        g = torch.randn(n, 2, generator=gen) * torch.rand(n, 1, generator=gen) ** 4 * 100
        radii = torch.randint(0, 3, (2, n), generator=gen, dtype=torch.int32).t()  # [N, 2], not contiguous
        unseen = (radii == 0).any(dim=-1)
        g[unseen & (torch.rand(n, generator=gen) < 0.2)] = float("nan")
        g[unseen & (torch.rand(n, generator=gen) < 0.2), 1] = float("inf")
        reloc.accumulate(state, g, radii)
        visible = (radii > 0).all(dim=-1)
        grad2d.add_(torch.where(visible, g.norm(dim=-1), 0.0))
        count.add_(visible)
    assert len(calls) == 20 and torch.isfinite(state["grad2d"]).all()
    assert torch.equal(state["grad2d"], grad2d) and torch.equal(state["count"], count)
    assert 0 < int(count.min()) < int(count.max()) < 20  # rows unseen in some passes, seen in others


def test_a_gaussian_drawn_nowhere_in_the_clip_is_dead_only_under_the_clip_rule():
    """``strategy.dead=clip_opacity``: a Gaussian whose opacity within the clip never exceeds
    min_opacity (its time far outside the clip) is relocated although its own o is high; the
    paper's rule (``opacity``) keeps it; sources come from the others only."""
    params, opt = make_params(n=50, n_dead=0)
    clip = torch.sigmoid(params["opacities"].detach()).clone()
    clip[40:] = 1e-4  # ten Gaussians that are never drawn within the clip
    paper = Relocator(StrategyConfig())
    assert paper.step(params, opt, paper.initialize_state(50), torch.Generator().manual_seed(1), clip) == 0
    before = params["means"].detach().clone()
    faded = Relocator(StrategyConfig(dead="clip_opacity"))
    assert faded.step(params, opt, faded.initialize_state(50), torch.Generator().manual_seed(1), clip) == 10
    moved_to = params["means"].detach()[40:]
    sources = (moved_to[:, None, :] == before[None, :40, :]).all(-1).any(-1)  # copies of the drawn ones
    assert bool(sources.all())
    with pytest.raises(InputError, match="strategy.dead"):
        Relocator(StrategyConfig(dead="never"))
    with pytest.raises(ValueError, match="clip_opacity"):  # the rule cannot fall back silently
        faded.step(params, opt, faded.initialize_state(50), torch.Generator().manual_seed(1))


def test_peak_opacity_in_a_window_is_at_the_gaussians_own_time_clipped_to_it():
    from ftgspp.config import InitConfig, ModelConfig
    from ftgspp.methods.freetime import FreeTimeGaussians

    n = 3
    times = np.array([0.5, -2.0, 3.0], np.float32)  # inside, before and after the window [0, 1]
    model = FreeTimeGaussians.from_points(np.zeros((n, 3), np.float32), np.full((n, 3), 0.5, np.float32), times,
                                          np.zeros((n, 3), np.float32), np.ones(n, np.float32), ModelConfig(),
                                          InitConfig(), "cpu")
    o, s = model.base_opacity().detach(), model.temporal_scale().detach()
    expect = o * torch.exp(-0.5 * ((torch.tensor([0.5, 0.0, 1.0]) - torch.from_numpy(times)) / s) ** 2)
    torch.testing.assert_close(model.peak_opacity(0.0, 1.0), expect)
    assert model.peak_opacity(0.0, 1.0)[0] == o[0]  # at its own time φ = 1
