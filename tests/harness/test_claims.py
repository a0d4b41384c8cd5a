"""Claims and verdicts on constructed runs: a planted effect is reproduced, a reverse one
contradicted, a planted effect inside ±SESOI equivalent, pure noise errs at the expected rate;
opposite effects on two scenes give scene-dependent rows; Brown–Forsythe against scipy and its
definition; prospective power against independent oracles (noncentral t, Cohen's tables, the
simulated Brown–Forsythe figures of the statistical audit); the paper-side test against
``ttest_ind_from_stats``; the family correction against hand-computed Holm and statsmodels."""

from __future__ import annotations

from pathlib import Path

import math

import numpy as np
import pandas as pd
import pytest
import yaml
from claimdata import claim, runs
from scipy import stats

from ftgspp.errors import InputError
from harness.analysis import claim_tests as C, stats as S, verdicts as V
from harness.spec.paper_register import PaperRow, Register, Statement
from harness.spec.study_files import load_study
from harness.spec.study_schema import ClaimSpec, Requires


def verdicts(df: pd.DataFrame, claims: list[ClaimSpec]) -> pd.DataFrame:
    return V.decide(V.evaluate(df, claims))


def test_family_correction_is_holm_as_computed_by_hand_and_by_statsmodels():
    from statsmodels.stats.multitest import multipletests

    # sorted: 0.005*4 = 0.02, 0.01*3 = 0.03, 0.03*2 = 0.06, 0.04*1 = 0.04 -> running max 0.06
    p = [0.01, 0.04, 0.03, 0.005, np.nan]
    np.testing.assert_allclose(S.family_adjust(p), [0.03, 0.06, 0.06, 0.02, np.nan])
    np.testing.assert_allclose(S.family_adjust(p[:4]), multipletests(p[:4], method="holm")[1])
    np.testing.assert_allclose(S.family_adjust(p[:4], "fdr_bh"), multipletests(p[:4], method="fdr_bh")[1])
    np.testing.assert_allclose(S.family_adjust([0.5, 0.6]), [1.0, 1.0])  # capped at 1


def test_family_adjust_skips_statsmodels_forced_collection_and_restores_gc(monkeypatch):
    """statsmodels' Holm branch calls gc.collect() on every call (seconds over a report's families):
    family_adjust runs it with the collection skipped, and gc.collect is gc.collect again after."""
    import gc

    calls = []
    monkeypatch.setattr(gc, "collect", lambda *a: calls.append(a) or 0)
    collect = gc.collect
    S.family_adjust([0.01, 0.04])
    assert calls == [] and gc.collect is collect
    from statsmodels.stats.multitest import multipletests

    multipletests([0.01, 0.04], method="holm")  # the reason: without the stand-in it collects
    assert len(calls) == 1


def test_one_family_across_studies_not_one_per_study():
    rng = np.random.default_rng(11)
    base = 30 + rng.normal(0, 0.3, 6)
    df = runs({("baseline", "s"): base, ("cc", "s"): base + 0.25 + rng.normal(0, 0.08, 6)})
    one = V.evaluate(df, [claim(id="x")])
    alone = V.decide(one)  # one claim: its difference and its equivalence test, one Holm over 2
    together = V.decide(pd.concat([one] * 5, ignore_index=True))  # the same claim in five studies: 10
    p, p_tost = float(one.p[0]), float(one.p_tost[0])
    assert alone.p_adj[0] == pytest.approx(S.union_adjust([p], [p_tost])[0][0])
    assert together.p_adj[0] == pytest.approx(S.family_adjust([p] * 5 + [p_tost] * 5)[0])
    assert together.p_adj[0] == pytest.approx(min(1.0, 10 * p))  # Holm's first step over 10 (p < p_tost)
    assert alone.family[0].endswith("Holm over 2 hypotheses") and together.family[0].endswith("over 10 hypotheses")
    ext = V.decide(pd.concat([one, one.assign(group="extension")], ignore_index=True))
    assert ext.p_adj.tolist() == pytest.approx([alone.p_adj[0]] * 2)  # another group is another family


def test_planted_effect_is_reproduced_and_reverse_effect_contradicted():
    rng = np.random.default_rng(0)
    base = 30 + rng.normal(0, 0.3, 8)  # seeds share their initialisation: paired noise
    df = runs({("baseline", "studio"): base, ("cc", "studio"): base + 0.4 + rng.normal(0, 0.05, 8),
               ("worse", "studio"): base - 0.4 + rng.normal(0, 0.05, 8)})
    out = verdicts(df, [claim(id="up"), claim(id="down", a="worse")])
    assert list(out.verdict) == [V.REPRODUCED, V.CONTRADICTED]
    up = out.iloc[0]
    assert up.method.startswith("paired") and up.n == "8 pairs"
    diff = df[df.variant == "cc"].psnr.to_numpy() - base
    half = stats.t.ppf(0.975, 7) * diff.std(ddof=1) / np.sqrt(8)  # the textbook paired CI
    assert up.effect == pytest.approx(diff.mean()) and up.effect == pytest.approx(0.4, abs=0.1)
    assert (up.ci_low, up.ci_high) == pytest.approx((diff.mean() - half, diff.mean() + half))
    assert up.statistic == pytest.approx(stats.ttest_rel(df[df.variant == "cc"].psnr, base).statistic)


def test_a_planted_effect_inside_the_sesoi_is_equivalent():
    rng = np.random.default_rng(12)
    base = 30 + rng.normal(0, 0.3, 10)
    df = runs({("baseline", "studio"): base, ("cc", "studio"): base + 0.02 + rng.normal(0, 0.03, 10)})
    row = verdicts(df, [claim(sesoi=0.1)]).iloc[0]
    assert row.verdict == V.EQUIVALENT and -0.1 < row.ci90_low and row.ci90_high < 0.1
    # the TOST is statsmodels' and agrees with two one-sided t-tests by hand
    d = df[df.variant == "cc"].psnr.to_numpy() - base
    lower = stats.ttest_1samp(d, -0.1, alternative="greater").pvalue
    upper = stats.ttest_1samp(d, 0.1, alternative="less").pvalue
    assert row.p_tost == pytest.approx(max(lower, upper))
    small = verdicts(df, [claim(sesoi=0.01)]).iloc[0]  # the same runs, a SESOI below the effect: a real gain
    assert small.verdict != V.EQUIVALENT and small.p < 0.05  # (one Holm over its two tests: p doubled)
    assert small.p_adj == pytest.approx(min(1.0, 2 * small.p))
    not_higher = verdicts(df, [claim(sesoi=0.1, expect="not_higher")]).iloc[0]
    assert not_higher.verdict == V.REPRODUCED  # "denser is not better": equivalence reproduces it


def test_opposite_effects_on_two_scenes_are_scene_dependent_not_pooled():
    rng = np.random.default_rng(13)
    base = {s: 30 + rng.normal(0, 0.3, 8) for s in ("slow", "fast")}
    df = runs({("baseline", "slow"): base["slow"], ("cc", "slow"): base["slow"] + 0.5 + rng.normal(0, 0.05, 8),
               ("baseline", "fast"): base["fast"], ("cc", "fast"): base["fast"] - 0.5 + rng.normal(0, 0.05, 8)})
    out = verdicts(df, [claim(scenes=("slow", "fast"))])
    assert list(out.id) == ["c[slow]", "c[fast]"] and out.scope.str.startswith("scene-dependent").all()
    assert list(out.verdict) == [V.REPRODUCED, V.CONTRADICTED] and (out.p_het < 1e-6).all()
    same = runs({("baseline", "slow"): base["slow"], ("cc", "slow"): base["slow"] + 0.5 + rng.normal(0, 0.05, 8),
                 ("baseline", "fast"): base["fast"], ("cc", "fast"): base["fast"] + 0.2 + rng.normal(0, 0.05, 8)})
    pooled = verdicts(same, [claim(scenes=("slow", "fast"))])  # heterogeneous but the same sign: pooled
    assert list(pooled.id) == ["c"] and pooled.verdict[0] == V.REPRODUCED


def test_pure_noise_errs_at_the_expected_rate():
    """Under the null a two-sided test at 0.05 errs 5% of the time, half in each direction."""
    rng = np.random.default_rng(1)
    out = []
    for _ in range(3000):
        a, b = rng.normal(0, 1, (2, 6))
        res = C.compare_means(a, b, paired=True, sesoi=0.01)
        out.append(V.verdict("higher", res.effect, "mean", res.p, res.p_tost))
    rate = {v: out.count(v) / len(out) for v in (V.REPRODUCED, V.CONTRADICTED, V.INCONCLUSIVE)}
    # binomial sd at n = 3000: 0.003 for 2.5%, 0.004 for 95%
    assert rate[V.REPRODUCED] == pytest.approx(0.025, abs=0.01)
    assert rate[V.CONTRADICTED] == pytest.approx(0.025, abs=0.01)
    assert rate[V.INCONCLUSIVE] == pytest.approx(0.95, abs=0.015)


def test_runs_needed_where_statsmodels_solver_stops_early():
    # ablation.gate_improves (issue 54): SESOI 0.2 dB, paired SD 0.07, alpha 0.05/39. statsmodels'
    # solve_power root-finds over a continuous n, where scipy's noncentral t returns NaN (at 5.5,
    # say), and stops at 5.2 (shown as 6). The oracle: simulated paired t-tests at n - 1 and n.
    sesoi, sd, alpha = 0.2, 0.0699934293760376, 0.05 / 39
    n = int(S.n_for_t(sesoi, sd, paired=True, alpha=alpha))
    assert n == 7
    rng = np.random.default_rng(54)

    def simulated(k: int) -> float:
        d = rng.normal(sesoi, sd, (20_000, k))
        return float((stats.ttest_1samp(d, 0.0, axis=1).pvalue < alpha).mean())

    assert simulated(n) >= 0.8 > simulated(n - 1)  # about 0.87 and 0.65
    # far out in the noncentral t's tail scipy returns NaN too; there the power is 1
    assert S.n_for_t(0.2, 0.3, paired=False) == 37 and S.n_for_t(0.2, 30.0, paired=False) == math.inf


def test_prospective_power_is_for_the_sesoi_not_the_observed_effect():
    # Cohen (1988) / G*Power, two-sided alpha 0.05, power 0.8: d = 0.5 -> 64 per group, 0.8 -> 26; paired 0.5 -> 34
    assert S.n_for_t(0.5, 1.0, paired=False) == 64
    assert S.n_for_t(0.8, 1.0, paired=False) == 26
    assert S.n_for_t(0.5, 1.0, paired=True) == 34
    # an independent oracle: the noncentral t's power at the returned n reaches 0.8, one fewer does not
    n = int(S.n_for_t(0.1, 0.15, paired=True))
    power = lambda k: (lambda tc: stats.nct.sf(tc, k - 1, 0.1 / 0.15 * np.sqrt(k))  # noqa: E731
                       + stats.nct.cdf(-tc, k - 1, 0.1 / 0.15 * np.sqrt(k)))(stats.t.ppf(0.975, k - 1))
    assert power(n) >= 0.8 > power(n - 1)
    rng = np.random.default_rng(14)
    base = 30 + rng.normal(0, 0.3, 6)
    cc = base + 0.05 + rng.normal(0, 0.2, 6)
    row = verdicts(runs({("baseline", "s"): base, ("cc", "s"): cc}), [claim(sesoi=0.3)]).iloc[0]
    sd = float(np.std(cc - base, ddof=1))
    # at the α the claim faces: its family holds 2 hypotheses (difference and equivalence), α/2
    assert row.verdict == V.INCONCLUSIVE and row.n_needed == S.n_for_t(0.3, sd, paired=True, alpha=0.025)
    assert row.n_needed > S.n_for_t(0.3, sd, paired=True)  # a stricter α needs more runs
    assert row.n_needed != S.n_for_t(abs(row.effect), sd, paired=True, alpha=0.025)  # not the observed effect's n


def test_brown_forsythe_power_by_simulation_matches_the_audit_and_f_overstates_it():
    rng = np.random.default_rng(17)
    a, b = rng.normal(0, 2, (50, 7)), rng.normal(0, 1, (50, 7))
    np.testing.assert_allclose(S.levene_median_p(a, b), [stats.levene(x, y, center="median").pvalue
                                                         for x, y in zip(a, b)])  # vectorised = scipy's
    ratio = np.sqrt(7.6)  # the paper's variance ratio (0.22 / 0.08)^2
    # the statistical audit's simulation: about 6.5% at n = 5 and 57% at n = 10 (Monte-Carlo sd ~1.1%)
    assert S.bf_power(ratio, 5) == pytest.approx(0.065, abs=0.03)
    assert S.bf_power(ratio, 10) == pytest.approx(0.57, abs=0.04)
    f_power = lambda k: stats.f.cdf(stats.f.ppf(0.025, k - 1, k - 1) / 7.6, k - 1, k - 1) + stats.f.sf(  # noqa: E731
        stats.f.ppf(0.975, k - 1, k - 1) / 7.6, k - 1, k - 1)
    assert f_power(5) > 0.35  # the F-test's power (41%) overstates Brown–Forsythe's by far
    n = S.n_for_bf(ratio)
    assert S.bf_power(ratio, int(n)) >= 0.8 > S.bf_power(ratio, int(n) - 1)


def test_paper_side_evidence_is_welch_from_summary_statistics():
    ev = S.paper_evidence(32.81, 32.47, 0.08, 0.22, 10)
    ref = stats.ttest_ind_from_stats(32.81, 0.08, 10, 32.47, 0.22, 10, equal_var=False)
    assert ev.p == pytest.approx(ref.pvalue) and ev.effect == pytest.approx(0.34)
    small = S.paper_evidence(32.64, 32.62, None, None, None, run_sd=0.22, run_sd_n=10)
    assert small.p > 0.5 and "run-to-run SD" in small.how  # a 0.02 dB gap is within the paper's own spread
    assert np.isnan(S.paper_evidence(1.0, 0.0, None, None, None).p)
    register = Register((Statement("s5_cc", "secret 5", "CC raises PSNR", "table", decided_by="st.c",
                                   numbers=(PaperRow("DyNeRF", 32.81, 32.47, 0.08, 0.22, 10),)),))
    row = V.evaluate(runs({("baseline", "s"): [30.0, 30.1, 29.9], ("cc", "s"): [30.2, 30.3, 30.1]}),
                     [claim()], "st", register).iloc[0]
    assert row.role == "decides" and row.statement_id == "s5_cc"
    assert "DyNeRF: 32.47 ± 0.22 → 32.81 ± 0.08 (10 runs)" in row.paper_numbers
    assert f"p = {ref.pvalue:.2g}" in row.paper_evidence and "distinguishable" in row.paper_evidence


def test_variance_claim_uses_brown_forsythe_equal_to_scipy_and_its_definition():
    rng = np.random.default_rng(3)
    a, b = rng.normal(30, 0.02, 12), rng.normal(30, 0.5, 12)
    df = runs({("baseline", "studio"): b, ("cc", "studio"): a})
    row = verdicts(df, [claim(test="variance", expect="lower", sesoi=2.0, pair="none")]).iloc[0]
    assert row.method.startswith("Brown–Forsythe") and row.stat_name == "W"
    ref = stats.levene(a, b, center="median")
    assert row.statistic == pytest.approx(ref.statistic) and row.p == pytest.approx(ref.pvalue)
    # definition: one-way ANOVA on absolute deviations from each group's median
    anova = stats.f_oneway(np.abs(a - np.median(a)), np.abs(b - np.median(b)))
    assert row.statistic == pytest.approx(anova.statistic)
    assert row.effect == pytest.approx(a.std(ddof=1) / b.std(ddof=1))
    assert row.ci_low <= row.effect <= row.ci_high
    assert row.verdict == V.REPRODUCED  # cc's spread is lower, as claimed
    flipped = V.evaluate(df, [claim(test="variance", expect="higher", a="baseline", b="cc", sesoi=2.0,
                                    pair="none")]).iloc[0]
    share = 1 - a.var(ddof=1) / b.var(ddof=1)  # fixed vs free init: the initialisation's share of the variance
    assert f"{share:.0%} of baseline's variance is not in cc" in flipped.detail


def test_variance_pooled_over_scenes_ignores_scene_means():
    rng = np.random.default_rng(4)
    noise_a, noise_b = rng.normal(0, 0.1, (2, 6)), rng.normal(0, 0.1, (2, 6))
    far = runs({("baseline", "s1"): 20 + noise_b[0], ("baseline", "s2"): 35 + noise_b[1],
                ("cc", "s1"): 20 + noise_a[0], ("cc", "s2"): 35 + noise_a[1]})
    near = runs({("baseline", "s1"): noise_b[0], ("baseline", "s2"): noise_b[1],
                 ("cc", "s1"): noise_a[0], ("cc", "s2"): noise_a[1]})
    c = [claim(test="variance", expect="lower", sesoi=2.0)]
    assert V.evaluate(far, c).statistic[0] == pytest.approx(V.evaluate(near, c).statistic[0])


def test_interaction_finds_a_planted_difference_of_differences():
    rng = np.random.default_rng(5)
    n = 8
    base_slow, base_fast = 30 + rng.normal(0, 0.2, n), 26 + rng.normal(0, 0.2, n)
    df = runs({("stride10", "slow"): base_slow, ("stride2", "slow"): base_slow + rng.normal(0, 0.05, n),
               ("stride10", "fast"): base_fast, ("stride2", "fast"): base_fast + 1.0 + rng.normal(0, 0.05, n)})
    c = claim(test="interaction", a="stride2", b="stride10", scenes=("fast", "slow"))
    row = verdicts(df, [c]).iloc[0]
    assert row.verdict == V.REPRODUCED and row.effect == pytest.approx(1.0, abs=0.1)
    assert row.ci_low < 1.0 < row.ci_high
    swapped = verdicts(df, [claim(test="interaction", a="stride2", b="stride10", scenes=("slow", "fast"))])
    assert swapped.verdict[0] == V.CONTRADICTED


def test_contrast_claims_hold_only_when_every_contrast_does():
    rng = np.random.default_rng(15)
    base = 30 + rng.normal(0, 0.3, 8)
    gains = {"base": 0.0, "flow": 0.1, "gate": 0.15, "cc": 0.8}
    df = runs({(v, "s"): base + g + rng.normal(0, 0.03, 8) for v, g in gains.items()})
    largest = claim(test="contrast", a="", b="", contrasts=(
        (("cc", 1.0), ("gate", -1.0), ("flow", -1.0), ("base", 1.0)), (("cc", 1.0), ("gate", -2.0), ("flow", 1.0))))
    row = verdicts(df, [largest]).iloc[0]
    assert row.verdict == V.REPRODUCED and "weakest contrast" in row.detail
    assert row.effect == pytest.approx(min(0.65 - 0.1, 0.65 - 0.05), abs=0.05)
    flat = df.assign(psnr=np.where(df.variant == "cc", df.psnr - 0.64, df.psnr))  # the CC gain is now 0.16
    assert verdicts(flat, [largest]).verdict[0] != V.REPRODUCED
    # the CC gain clearly below flow's and barely above the gate's: the contrast against the claim
    # decides (the audit's "CC gain - flow gain = -0.71 dB"), not the one with the larger p
    against = runs({(v, "s"): base + g + rng.normal(0, 0.03, 8)
                    for v, g in {"base": 0.0, "flow": 0.8, "gate": 0.8, "cc": 0.95}.items()})
    row = verdicts(against, [largest]).iloc[0]
    assert row.effect == pytest.approx(0.15 - 0.8, abs=0.05) and row.verdict == V.CONTRADICTED


def test_existential_decoupling_finds_equal_rgb_with_different_motion():
    rng = np.random.default_rng(16)
    base = 30 + rng.normal(0, 0.2, 8)
    df = runs({("baseline", "s"): base, ("flow", "s"): base + rng.normal(0, 0.02, 8)})
    df["motion_epe_dynamic"] = np.where(df.variant == "flow", 0.5, 1.0) + rng.normal(0, 0.03, len(df))
    c = claim(test="decoupled", expect="exists", versus="motion_epe_dynamic", a="", b="", sesoi=0.1)
    row = verdicts(df, [c]).iloc[0]
    assert row.verdict == V.REPRODUCED and "best pair baseline vs flow on s" in row.detail
    coupled = df.assign(motion_epe_dynamic=np.where(df.variant == "flow", 1.0, 1.0) + rng.normal(0, 0.03, len(df)))
    assert verdicts(coupled, [c]).verdict[0] == V.INCONCLUSIVE  # equal RGB and equal motion: no example


def test_one_sample_claim_on_a_per_run_gap():
    rng = np.random.default_rng(7)
    df = runs({("baseline", "studio"): -0.03 + rng.normal(0, 0.005, 6)}, metric="gap_lpips_alex")
    row = verdicts(df, [claim(metric="gap_lpips_alex", a="baseline", b="", expect="lower", sesoi=0.005)]).iloc[0]
    assert row.method.startswith("one-sample") and row.verdict == V.REPRODUCED and row.effect < 0


def test_missing_runs_are_not_tested_and_an_absent_mechanism_not_exercised():
    rng = np.random.default_rng(8)
    base = rng.normal(30, 0.3, 6)
    df = runs({("baseline", "studio"): base, ("cc", "studio"): base + 1 + rng.normal(0, 0.05, 6)})
    df.loc[df.variant == "cc", "status"] = ["FINISHED"] * 5 + ["FAILED"]
    df["relocated_total"] = 60.0
    out = verdicts(df, [claim(id="ok"), claim(id="gone", a="free_init"), claim(id="nowhere", scenes=("fast",)),
                        claim(id="nometric", metric="flicker_static"),
                        claim(id="idle", requires=(Requires("relocated_total", 1000.0),)),
                        claim(id="outdoor", scenes=("actor1_4",), needs="ENeRF-Outdoor (ENERF_OUTDOOR_ROOT)")])
    assert out.n[0] == "5 pairs"  # the failed run's pair is dropped, not imputed
    assert list(out.verdict) == [V.REPRODUCED, V.NOT_TESTED, V.NOT_TESTED, V.NOT_TESTED, V.NOT_EXERCISED,
                                 V.NOT_TESTED]
    assert out.note[5] == "needs real data: ENeRF-Outdoor (ENERF_OUTDOOR_ROOT)"
    assert "free_init" in out.note[1] and "fast" in out.note[2] and "flicker_static" in out.note[3]
    assert "median `relocated_total` 60 < 1000" in out.note[4]
    assert out.p_adj[0] == pytest.approx(min(1.0, 2 * out.p[0]))  # one tested claim: its two tests, one Holm


# --------------------------------------------------------------------------- schema


def _study_with(tmp_path: Path, claims: list[dict]) -> Path:
    raw = yaml.safe_load((Path(__file__).parent / "studies" / "toy.yaml").read_text())
    raw["claims"] = claims
    (tmp_path / "toy.yaml").write_text(yaml.safe_dump(raw))
    return tmp_path


GOOD = {"id": "cc_mean", "claim": "CC raises PSNR.", "metric": "psnr", "test": "mean", "a": "cc", "b": "baseline",
        "scenes": ["easy"], "expect": "higher"}


def test_claims_load_as_data_with_the_metric_registrys_smallest_effect(tmp_path: Path):
    from harness.spec.metrics import SD_RATIO_SESOI, lookup

    study = load_study("toy", _study_with(tmp_path, [GOOD, {**GOOD, "id": "spread", "test": "variance",
                                                            "expect": "lower", "group": "extension"}]))
    assert [c.id for c in study.claims] == ["cc_mean", "spread"]
    first, second = study.claims
    assert first.pair == "seed" and first.group == "paper"
    assert first.sesoi == lookup("psnr").smallest_effect and first.sesoi_source == "docs/sesoi.md, psnr"
    assert second.group == "extension" and second.sesoi == SD_RATIO_SESOI  # a variance claim: an SD ratio


@pytest.mark.parametrize("change, words", [
    ({"metric": "psnr2"}, "unknown metric 'psnr2'"),
    ({"a": "nosuch"}, "unknown variant 'nosuch'"),
    ({"test": "anova"}, "unknown comparison 'anova'"),
    ({"expect": "exists"}, "not an expectation of a mean test"),
    ({"sesoi": 0.34}, "unknown key(s) sesoi"),  # fixed per metric in the registry, never per claim
    ({"metric": "n_gaussians"}, "no smallest effect of interest"),
    ({"group": "mine"}, "unknown group 'mine'"),
    ({"test": "interaction", "pairs": [["cc", "baseline"]], "a": "", "b": "", "scenes": ["easy", "real"]},
     "one [a, b] per scene"),
    ({"scenes": []}, "name the claim's scenes"),
    ({"scenes": ["hard"]}, "unknown scene 'hard'"),
    ({"requires": [{"metric": "flicker_static"}]}, "give either min or above"),
    ({"test": "interaction", "scenes": ["easy"]}, "exactly two scenes"),
    ({"colour": 1}, "unknown key(s) colour"),
])
def test_bad_claims_are_one_line_exit_2(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                        capsys: pytest.CaptureFixture[str], change: dict, words: str):
    import harness.spec.study_files
    from harness.cli.study import main

    root = _study_with(tmp_path, [{**GOOD, **change}])
    with pytest.raises(InputError, match=None) as err:
        load_study("toy", root)
    assert words in str(err.value)
    monkeypatch.setattr(harness.spec.study_files, "STUDIES_DIR", root)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        main(["report", "toy"])
    assert exc.value.code == 2
    lines = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert len(lines) == 1 and words in lines[0] and "claims" in lines[0]


def test_every_secret_states_its_claims():
    """The index needs a row for each secret, the ablation and the CC-per-scene claim."""
    names = ("secret1", "secret2", "secret3", "secret4", "secret5", "secret5_cc", "ablation", "lpips")
    tests = {name: {c.test for c in load_study(name).claims} for name in names}
    assert all(tests.values()), tests
    for name in names:
        for c in load_study(name).claims:
            assert c.sesoi > 0 and c.sesoi_source, f"{name}.{c.id} states no smallest effect of interest"
    from harness.spec.study_files import load_register

    with_numbers = [s for s in load_register().statements
                    if any(r.a is not None or r.a_std is not None for r in s.numbers)]
    assert len(with_numbers) >= 12  # the paper's numbers, as data
    assert "dissociated" in tests["secret2"] and "interaction" in tests["secret3"]
    assert {"mean", "variance"} <= tests["secret5_cc"] and "variance" in tests["secret5"]
    # colour correction is judged per scene: static gains and exposure drift apart
    assert {c.scenes for c in load_study("secret5_cc").claims} == {("studio",), ("exposure_drift",)}
    assert "variance" in tests["secret5"] and "spread" in tests["secret5"]
    per_scene = [c for c in load_study("ablation").claims if c.scenes == ("color_shift",)]
    assert per_scene and per_scene[0].a == "flow_gate_cc" and per_scene[0].b == "flow_gate"
