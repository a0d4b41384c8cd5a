"""Runs until decided (issue 57), proved by simulation: the t boundaries against the published
Lan–DeMets z boundaries; the sequential p-values against the verdict code's; each hypothesis
spends its α share on t at 3 runs; a family mixing difference nulls (effect 0) and equivalence
nulls (effect at ±SESOI) errs at most α, while peeking at fixed-n levels after every round does
not; a true effect stops earlier than the fixed design with at least its power; a family never
reads another family's runs; the round-by-round API is the simulated procedure; scene instances
as the unit keep α where seed-as-unit does not.

Monte-Carlo margins: an error rate from R simulated families has SD √(α(1 − α)/R) (0.0015 at
R = 20 000, 0.0009 at 60 000); the boundaries' own calibration on 2^18 null paths adds 1/√(2^18·share) of a
share. Every simulation has a fixed seed."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from harness.analysis import claim_tests as C, instance_unit as I, sequential as Q, stats as S

ALPHA = 0.05


def _claim(name: str, rng: np.random.Generator, reps: int, plan: Q.Plan, effect: float, sesoi: float = 1.0,
           sd_b: float | None = None, **kw) -> Q.Claim:
    """A claim with ``reps`` simulated copies: paired differences N(effect, 1) (``sd_b`` None), or
    Welch arms N(effect, 1) and N(0, sd_b²)."""
    a = rng.normal(effect, 1.0, (reps, plan.n_max))
    b = None if sd_b is None else rng.normal(0.0, sd_b, (reps, plan.n_max))
    return Q.Claim(name, a, b, sesoi, paired=sd_b is None, plan=plan, **kw)


def test_t_boundaries_at_large_n_are_the_published_lan_demets_z_boundaries():
    # Lan–DeMets spending, 5 equally spaced looks, one-sided α = 0.025: the z boundaries of R's gsDesign
    # (gsDesign(k = 5, test.type = 1, alpha = 0.025, sfu = sfLDOF or sfLDPocock); reproduced with the
    # `gsdesign` package's numerical integration when the design was chosen). At 200..1000 runs t is z.
    published = {"obf": [4.877, 3.357, 2.680, 2.290, 2.031], "pocock": [2.438, 2.427, 2.410, 2.397, 2.386]}
    looks = (200, 400, 600, 800, 1000)
    for spending, z in published.items():
        c = stats.norm.isf(Q.nominal_levels(looks, 1000, 0.025, False, spending))
        # the first O'Brien–Fleming look spends 5e-7, under one of the 2^18 paths: it cannot stop (c = inf)
        first = 1 if spending == "obf" else 0
        np.testing.assert_allclose(c[first:], z[first:], atol=0.04)
        assert first == 0 or math.isinf(c[0])
    # one look is the fixed test at α (its order statistic among the null paths' p)
    assert Q.nominal_levels((12,), 12, 0.05, True)[0] == pytest.approx(0.05, rel=0.02)
    assert Q.nominal_levels((3, 5, 7), 7, 0.05, spending="none").tolist() == [0.05] * 3


def test_sequential_pvalues_are_the_verdict_codes():
    rng = np.random.default_rng(1)
    for expect in ("higher", "equivalent"):
        a, b = rng.normal(0.4, 1, 7), rng.normal(0, 1, 7)
        ref = C.compare_means(a, b, True, 0.5)  # the verdicts' paired t, statsmodels' TOST
        p, p_tost = Q.pvalues(a, b, 0.5, True, expect)
        assert float(p) == pytest.approx(ref.p_outside if expect == "equivalent" else ref.p)
        assert float(p_tost) == pytest.approx(ref.p_tost)
        one = C.compare_means(a, None, True, 0.5)
        assert float(Q.pvalues(a, None, 0.5, expect=expect)[1]) == pytest.approx(one.p_tost)
    # Welch: the same statistic at min(n) − 1 degrees of freedom, so never below the verdicts' p
    # where it could reject (a one-sided p above ½ moves the other way)
    a, b = rng.normal(0.4, 1, 6), rng.normal(0, 3, 8)
    ref = C.compare_means(a, b, False, 0.5)
    p, p_tost = Q.pvalues(a, b, 0.5, False)
    assert float(p) == pytest.approx(2 * stats.t.sf(abs(ref.statistic), 5))
    assert p >= ref.p and min(p_tost, 0.5) >= min(ref.p_tost, 0.5)
    # vectorised over many experiments: each row is the one-at-a-time p
    many = rng.normal(0, 1, (4, 5))
    assert Q.pvalues(many, None, 0.5)[0] == pytest.approx([Q.pvalues(r, None, 0.5)[0] for r in many])


@pytest.mark.parametrize("spending", ["obf", "pocock"])
def test_each_hypothesis_spends_its_share_on_t_from_three_runs(spending: str):
    # one claim, family α = 0.1 over its 2 hypotheses; a tiny SESOI never gives equivalence, so
    # the difference hypothesis holds α/2 = 0.05 at every look: its size is the share, at 3..13 pairs
    rng = np.random.default_rng(2)
    reps = 60_000
    plan = Q.Plan(first=3, per_round=2, rounds=6, arms=1)
    for alternative in ("two-sided", "greater"):
        rejected, _ = Q.simulate([_claim("d0", rng, reps, plan, 0.0, 1e-9, alternative=alternative)], 0.1, spending)
        assert rejected[0, 0].mean() == pytest.approx(0.05, abs=0.0035)  # 3.5 SD of simulation and calibration
    # Welch reads its statistic at min(n) − 1 degrees of freedom: at most the share, equal or
    # unequal spreads (Welch–Satterthwaite's own df overshoots: ~0.053 at SD ratio 3)
    for sd_b in (1.0, 10.0):
        rejected, _ = Q.simulate([_claim("w0", rng, 40_000, Q.Plan(3, 2, 6), 0.0, 1e-9, sd_b)], 0.1, spending)
        assert rejected[0, 0].mean() <= 0.05 + 3 * math.sqrt(0.05 * 0.95 / 40_000)


def _mixed_nulls(rng: np.random.Generator, reps: int) -> tuple[list[Q.Claim], np.ndarray]:
    """A family of 5 claims with SESOI 1 (SD 1) and which of their hypotheses are true nulls:
    two difference nulls (effect 0; one paired, one Welch), two equivalence nulls at +SESOI and
    −SESOI, one "≈" claim exactly at +SESOI (both its minimal-effect and equivalence nulls hold)."""
    plan, single = Q.Plan(3, 2, 6), Q.Plan(3, 2, 6, arms=1)
    claims = [_claim("zero", rng, reps, single, 0.0), _claim("zero_welch", rng, reps, plan, 0.0, sd_b=2.0),
              _claim("at_plus", rng, reps, single, 1.0), _claim("at_minus", rng, reps, single, -1.0),
              _claim("approx", rng, reps, single, 1.0, expect="equivalent")]
    true_null = np.array([[True, False], [True, False], [False, True], [False, True], [True, True]])
    return claims, true_null


def test_family_error_under_mixed_nulls_is_at_most_alpha_and_naive_peeking_exceeds_it():
    reps = 20_000
    margin = 3 * math.sqrt(ALPHA * (1 - ALPHA) / reps)  # 0.0046
    claims, true_null = _mixed_nulls(np.random.default_rng(3), reps)
    fwer = {}
    for spending in ("obf", "pocock", "none"):
        rejected, _ = Q.simulate(claims, ALPHA, spending)
        fwer[spending] = (rejected & true_null[:, :, None]).any(axis=(0, 1)).mean()
    assert fwer["obf"] <= ALPHA + margin and fwer["pocock"] <= ALPHA + margin  # ~0.027 and ~0.020
    assert fwer["none"] > ALPHA + margin  # Holm at fixed-n levels after each of 6 rounds: ~0.093
    # the contrast for one hypothesis: 6 looks at a fixed-n 0.05 reject a true null ~3x as often
    rejected, _ = Q.simulate([_claim("d0", np.random.default_rng(4), reps, Q.Plan(3, 2, 6, arms=1), 0.0, 1e-9)],
                             0.1, "none")
    assert rejected[0, 0].mean() > 0.1


def test_a_true_effect_stops_earlier_than_the_fixed_design_with_its_power():
    # effect = SESOI = SD: the fixed paired t at the family's first Holm step (α/2) needs 13 pairs
    rng = np.random.default_rng(5)
    n_fixed = int(S.n_for_t(1.0, 1.0, True, ALPHA / 2))
    assert n_fixed == 13
    reps = 20_000
    a = rng.normal(1.0, 1.0, (reps, 15))
    sequential = Q.Claim("effect", a, None, 1.0, plan=Q.Plan(3, 2, 7, arms=1))  # looks at 3, 5, .., 15
    fixed = Q.Claim("effect", a[:, :n_fixed], None, 1.0, plan=Q.Plan(n_fixed, 1, 1, arms=1))  # one look
    rej_seq, used = Q.simulate([sequential])
    rej_fixed, _ = Q.simulate([fixed])
    assert rej_fixed[0, 0].mean() == pytest.approx(S.t_power(1.0, 1.0, n_fixed, True, ALPHA / 2), abs=0.01)
    assert rej_seq[0, 0].mean() >= rej_fixed[0, 0].mean()  # ~0.87 against ~0.84
    assert used.mean() < n_fixed - 1  # ~11.8 pairs on average against 13


def test_decide_family_round_by_round_is_the_simulated_procedure():
    rng = np.random.default_rng(6)
    reps = 24
    claims, _ = _mixed_nulls(rng, reps)
    claims[2] = _claim("big", rng, reps, Q.Plan(3, 2, 6, arms=1), 2.5)  # decided early, recycling α
    rejected, used = Q.simulate(claims)
    for r in range(reps):
        state = None
        for k in range(6):
            now = [Q.Claim(c.name, c.a[r, :c.plan.schedule()[k]], None if c.b is None else c.b[r, :c.plan.schedule()[k]],
                           c.sesoi, c.paired, c.expect, c.alternative, c.plan) for c in claims]
            decisions, state = Q.decide_family(now, state)
        assert [[h in d.rejected for h in Q.HYPOTHESES] for d in decisions] == rejected[:, :, r].tolist()
        assert [d.n for d in decisions] == used[:, r].tolist()
        assert all((d.status == Q.DECIDED) == bool(d.rejected) for d in decisions)
    assert rejected[2, 0].all()  # the large effect is always found


def test_a_family_never_reads_another_familys_runs():
    rng = np.random.default_rng(7)
    plan = Q.Plan(3, 2, 4, arms=1)
    family_a = [Q.Claim(f"a{i}", rng.normal(e, 1, 5), None, 1.0, plan=plan) for i, e in enumerate((0.0, 2.0))]

    def other(effect: float) -> list[Q.Claim]:
        return [Q.Claim("b0", rng.normal(effect, 0.1, 5), None, 1.0, plan=plan)]

    first, state_1 = Q.decide_study({"A": family_a, "B": other(0.0)})
    again, state_2 = Q.decide_study({"A": family_a, "B": other(5.0)})  # B now decides at once
    assert again["A"] == first["A"] and state_2["A"] == state_1["A"]
    assert again["B"] != first["B"] and again["B"][0].status == Q.DECIDED
    alone, _ = Q.decide_family(family_a)
    assert alone == first["A"]


def test_caps_cut_the_plan_and_a_claim_at_its_cap_says_how_many_runs_it_needs():
    plan = Q.Plan(first=3, per_round=2, rounds=6, cap_runs=18, arms=2)  # 13 pairs planned, 9 allowed
    assert plan.n_max == 9 and plan.schedule() == (3, 5, 7, 9)
    assert Q.Plan(3, 2, 6, cap_cpu_hours=10.0, cpu_hours_per_run=0.5).schedule() == (3, 5, 7, 9, 10)
    with pytest.raises(ValueError):
        Q.Plan(3, 2, 6, cap_runs=3).n_max
    rng = np.random.default_rng(8)
    a, b = rng.normal(0.3, 1, 9), rng.normal(0, 1, 9)
    claim = Q.Claim("small", a, b, 0.2, plan=plan)
    state = None
    for n in (3, 5, 7, 9):
        (decision,), state = Q.decide_family([Q.Claim("small", a[:n], b[:n], 0.2, plan=plan)], state)
        assert decision.runs_next == (4 if n < 9 else 0) or decision.status == Q.DECIDED
    assert decision.status == Q.AT_CAP and decision.verdict == "inconclusive"
    assert state["small"]["looks"] == [3, 5, 7, 9]
    assert decision.runs_needed == S.n_for_t(0.2, float(np.std(a - b, ddof=1)), True, ALPHA / 2)
    (same,), _ = Q.decide_family([claim], state)  # no new runs: read again at its last look
    assert same == decision


def _instances(rng: np.random.Generator, k: int = 6, seeds: int = 5, tau: float = 1.0, sigma: float = 0.2
               ) -> pd.DataFrame:
    """Runs of variants a and b on k instances of one scene: an instance level shared by both
    variants, an effect of a that varies by instance (SD ``tau``, mean 0) and seed noise ``sigma``."""
    level, effect = rng.normal(0, 1, (k, 1)), rng.normal(0, tau, (k, 1))
    b = 30 + level + rng.normal(0, sigma, (k, seeds))
    a = b + effect + rng.normal(0, sigma, (k, seeds))
    instance, seed = np.meshgrid(np.arange(k), np.arange(seeds), indexing="ij")
    return pd.DataFrame({"variant": np.repeat(["a", "b"], k * seeds), "scene": "studio",
                         "instance": np.tile(instance.ravel(), 2), "seed": np.tile(seed.ravel(), 2),
                         "psnr": np.concatenate([a.ravel(), b.ravel()])})


def test_instance_as_unit_keeps_alpha_where_seed_as_unit_does_not():
    # the effect varies by instance (SD 1) far more than by seed (0.2); its mean is 0
    rng = np.random.default_rng(9)
    reps = 200
    frames = [_instances(rng) for _ in range(reps)]
    seed_unit = np.mean([I.seed_unit_p(df, "psnr", "a", "b") < ALPHA for df in frames])
    instance_unit = np.mean([I.instance_test(df, "psnr", "a", "b", 0.2).p < ALPHA for df in frames])
    assert seed_unit > 0.25  # 30 pseudo-replicated pairs: ~0.4
    assert instance_unit <= ALPHA + 3 * math.sqrt(ALPHA * (1 - ALPHA) / reps)  # 6 instances: ~0.05


def test_mixed_model_with_instance_effects_is_the_instance_means_test_on_a_balanced_design():
    rng = np.random.default_rng(10)
    for _ in range(3):
        df = _instances(rng)
        mixed, means = I.mixed_model_test(df, "psnr", "a", "b"), I.instance_test(df, "psnr", "a", "b", 0.2)
        assert mixed.converged and mixed.instances == 6 and mixed.dof == 5
        assert mixed.effect == pytest.approx(means.effect, abs=1e-8)
        assert mixed.p == pytest.approx(means.p, rel=0.01)
    # unbalanced seeds per instance still fit; the instance means weigh every instance alike
    df = _instances(rng).drop(index=[0, 1, 2])
    means = I.instance_means(df, "psnr")
    assert means[(means.variant == "a") & (means.instance == 0)].runs.item() == 2
    assert I.mixed_model_test(df, "psnr", "a", "b").converged
    assert I.instance_test(df, "psnr", "a", "b", 0.2).n == "6 instances"
