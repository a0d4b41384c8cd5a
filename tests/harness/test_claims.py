"""Claims: verdicts on constructed runs (planted effect, planted reverse effect, pure noise at
the expected false-positive rate), Holm against hand-computed values, Brown–Forsythe against
scipy and the ANOVA-on-deviations definition, power against Cohen's tables, and the schema."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from scipy import stats

from ftgspp.errors import InputError
from harness.analysis import claims as C
from harness.spec.files import load_study
from harness.spec.study import ClaimSpec


def runs(values: dict[tuple[str, str], np.ndarray], metric: str = "psnr") -> pd.DataFrame:
    """A runs frame like ``aggregate.runs_frame``: {(variant, scene): per-seed values}."""
    rows = [{"variant": v, "scene": s, "seed": i, "status": "FINISHED", metric: float(x)}
            for (v, s), xs in values.items() for i, x in enumerate(xs)]
    return pd.DataFrame(rows)


def claim(**kw: object) -> ClaimSpec:
    base = {"id": "c", "statement": "s", "metric": "psnr", "test": "mean", "expect": "higher", "a": "cc",
            "b": "baseline"}
    return ClaimSpec(**{**base, **kw})


def test_holm_matches_hand_computed_values():
    # sorted: 0.005*4 = 0.02, 0.01*3 = 0.03, 0.03*2 = 0.06, 0.04*1 = 0.04 -> running max 0.06
    p = [0.01, 0.04, 0.03, 0.005, np.nan]
    np.testing.assert_allclose(C.holm(p), [0.03, 0.06, 0.06, 0.02, np.nan])
    np.testing.assert_allclose(C.holm([0.5, 0.6]), [1.0, 1.0])  # capped at 1
    assert np.isnan(C.holm([np.nan])).all()


def test_planted_effect_is_reproduced_and_reverse_effect_contradicted():
    rng = np.random.default_rng(0)
    base = 30 + rng.normal(0, 0.3, 8)  # seeds share their initialisation: paired noise
    df = runs({("baseline", "studio"): base, ("cc", "studio"): base + 0.4 + rng.normal(0, 0.05, 8),
               ("worse", "studio"): base - 0.4 + rng.normal(0, 0.05, 8)})
    out = C.evaluate(df, [claim(id="up"), claim(id="down", a="worse")])
    assert list(out.verdict) == [C.REPRODUCED, C.CONTRADICTED]
    up = out.iloc[0]
    assert up.method.startswith("paired") and up.n == "8 pairs"
    diff = df[df.variant == "cc"].psnr.to_numpy() - base
    half = stats.t.ppf(0.975, 7) * diff.std(ddof=1) / np.sqrt(8)  # the textbook paired CI
    assert up.effect == pytest.approx(diff.mean()) and up.effect == pytest.approx(0.4, abs=0.1)
    assert (up.ci_low, up.ci_high) == pytest.approx((diff.mean() - half, diff.mean() + half))
    assert up.p_holm < 0.05
    assert up.statistic == pytest.approx(stats.ttest_rel(df[df.variant == "cc"].psnr, base).statistic)
    assert out.p_holm.tolist() == pytest.approx(C.holm(out.p.to_numpy()).tolist())


def test_pure_noise_is_inconclusive_at_the_expected_rate():
    """Under the null a two-sided test at 0.05 errs 5% of the time, half in each direction."""
    rng = np.random.default_rng(1)
    verdicts = []
    for _ in range(3000):
        a, b = rng.normal(0, 1, (2, 6))
        res = C.compare_means(a, b, paired=True)
        verdicts.append(C.verdict(C.holm([res.p])[0], res.effect, "higher"))
    rate = {v: verdicts.count(v) / len(verdicts) for v in (C.REPRODUCED, C.CONTRADICTED, C.INCONCLUSIVE)}
    # binomial sd at n = 3000: 0.003 for 2.5%, 0.004 for 95%
    assert rate[C.REPRODUCED] == pytest.approx(0.025, abs=0.01)
    assert rate[C.CONTRADICTED] == pytest.approx(0.025, abs=0.01)
    assert rate[C.INCONCLUSIVE] == pytest.approx(0.95, abs=0.015)


def test_variance_test_on_equal_spreads_errs_at_about_alpha():
    rng = np.random.default_rng(9)
    verdicts = []
    for _ in range(600):
        res = C.compare_variances(*rng.normal(0, 1, (2, 10)))
        verdicts.append(C.verdict(res.p, res.effect, "lower"))
    decided = 1 - verdicts.count(C.INCONCLUSIVE) / len(verdicts)
    assert 0.015 < decided < 0.09  # 5% nominal (binomial sd 0.009); Brown–Forsythe is a little conservative
    assert verdicts.count(C.REPRODUCED) and verdicts.count(C.CONTRADICTED)  # both directions err


def test_noise_through_the_whole_path_and_needed_n():
    rng = np.random.default_rng(2)
    df = runs({("baseline", "studio"): rng.normal(30, 0.2, 5), ("cc", "studio"): rng.normal(30, 0.2, 5)})
    out = C.evaluate(df, [claim(pair="none")])
    row = out.iloc[0]
    assert row.method == "Welch t" and row.n == "5 vs 5"
    assert row.verdict == C.INCONCLUSIVE  # the needed n follows the observed standardised effect
    a, b = df[df.variant == "cc"].psnr, df[df.variant == "baseline"].psnr
    d = (a.mean() - b.mean()) / np.sqrt((a.var() + b.var()) / 2)
    assert row.n_needed == C.n_for_t_test(d, paired=False) and row.n_needed > 5


def test_needed_n_matches_cohens_tables():
    # Cohen (1988) / G*Power, two-sided alpha 0.05, power 0.8: d = 0.5 -> 64 per group, 0.8 -> 26; paired 0.5 -> 34
    assert C.n_for_t_test(0.5, paired=False) == 64
    assert C.n_for_t_test(0.8, paired=False) == 26
    assert C.n_for_t_test(0.5, paired=True) == 34
    assert C.n_for_t_test(0.0, paired=True) == np.inf
    # variance ratio 4 (std x2): the F-test's power at the returned n reaches 0.8, one fewer does not
    n = int(C.n_for_variance_test(4.0))
    lo, hi = stats.f.ppf(0.025, n - 1, n - 1), stats.f.ppf(0.975, n - 1, n - 1)
    power = lambda k: stats.f.cdf(stats.f.ppf(0.025, k - 1, k - 1) / 4, k - 1, k - 1) + stats.f.sf(  # noqa: E731
        stats.f.ppf(0.975, k - 1, k - 1) / 4, k - 1, k - 1)
    assert power(n) >= 0.8 > power(n - 1) and lo < 1 < hi


def test_variance_claim_uses_brown_forsythe_equal_to_scipy_and_its_definition():
    rng = np.random.default_rng(3)
    a, b = rng.normal(30, 0.02, 12), rng.normal(30, 0.5, 12)
    df = runs({("baseline", "studio"): b, ("cc", "studio"): a})
    row = C.evaluate(df, [claim(test="variance", expect="lower")]).iloc[0]
    assert row.method.startswith("Brown–Forsythe") and row.stat_name == "W"
    ref = stats.levene(a, b, center="median")
    assert row.statistic == pytest.approx(ref.statistic) and row.p == pytest.approx(ref.pvalue)
    # definition: one-way ANOVA on absolute deviations from each group's median
    anova = stats.f_oneway(np.abs(a - np.median(a)), np.abs(b - np.median(b)))
    assert row.statistic == pytest.approx(anova.statistic)
    assert row.effect == pytest.approx(a.std(ddof=1) - b.std(ddof=1))
    assert row.ci_low <= row.effect <= row.ci_high
    assert row.verdict == C.REPRODUCED  # cc's spread is lower, as claimed
    flipped = C.evaluate(df, [claim(test="variance", expect="higher", a="baseline", b="cc")]).iloc[0]
    share = 1 - a.var(ddof=1) / b.var(ddof=1)  # fixed vs free init: the initialisation's share of the variance
    assert f"{share:.0%} of baseline's variance is not in cc" in flipped.detail


def test_variance_pooled_over_scenes_ignores_scene_means():
    rng = np.random.default_rng(4)
    noise_a, noise_b = rng.normal(0, 0.1, (2, 6)), rng.normal(0, 0.1, (2, 6))
    far = runs({("baseline", "s1"): 20 + noise_b[0], ("baseline", "s2"): 35 + noise_b[1],
                ("cc", "s1"): 20 + noise_a[0], ("cc", "s2"): 35 + noise_a[1]})
    near = runs({("baseline", "s1"): noise_b[0], ("baseline", "s2"): noise_b[1],
                 ("cc", "s1"): noise_a[0], ("cc", "s2"): noise_a[1]})
    c = [claim(test="variance", expect="lower")]
    assert C.evaluate(far, c).statistic[0] == pytest.approx(C.evaluate(near, c).statistic[0])


def test_interaction_finds_a_planted_difference_of_differences():
    rng = np.random.default_rng(5)
    n = 8
    base_slow, base_fast = 30 + rng.normal(0, 0.2, n), 26 + rng.normal(0, 0.2, n)
    df = runs({("stride10", "slow"): base_slow, ("stride2", "slow"): base_slow + rng.normal(0, 0.05, n),
               ("stride10", "fast"): base_fast, ("stride2", "fast"): base_fast + 1.0 + rng.normal(0, 0.05, n)})
    c = claim(test="interaction", a="stride2", b="stride10", scenes=("fast", "slow"))
    row = C.evaluate(df, [c]).iloc[0]
    assert row.verdict == C.REPRODUCED and row.effect == pytest.approx(1.0, abs=0.1)
    assert row.ci_low < 1.0 < row.ci_high
    swapped = C.evaluate(df, [claim(test="interaction", a="stride2", b="stride10", scenes=("slow", "fast"))])
    assert swapped.verdict[0] == C.CONTRADICTED


def test_weak_correlation_reproduced_for_independent_metrics_contradicted_for_coupled():
    rng = np.random.default_rng(6)
    x = rng.normal(30, 1, 120)
    df = pd.DataFrame({"variant": "v", "scene": np.repeat(["s1", "s2"], 60), "seed": np.arange(120),
                       "status": "FINISHED", "psnr": x, "motion_epe_dynamic": rng.normal(1, 0.1, 120)})
    c = claim(test="correlation", expect="weak", versus="motion_epe_dynamic", a="", b="")
    row = C.evaluate(df, [c]).iloc[0]
    assert row.verdict == C.REPRODUCED and abs(row.effect) < 0.3
    assert row.effect == pytest.approx(stats.pearsonr(x - np.repeat([x[:60].mean(), x[60:].mean()], 60),
                                                      df.motion_epe_dynamic - df.groupby("scene").motion_epe_dynamic
                                                      .transform("mean")).statistic)
    coupled = df.assign(motion_epe_dynamic=-0.1 * x + rng.normal(0, 0.01, 120))
    assert C.evaluate(coupled, [c]).verdict[0] == C.CONTRADICTED


def test_one_sample_claim_on_a_per_run_gap():
    rng = np.random.default_rng(7)
    df = runs({("baseline", "studio"): -0.03 + rng.normal(0, 0.005, 6)}, metric="gap_lpips_alex")
    row = C.evaluate(df, [claim(metric="gap_lpips_alex", a="baseline", b="", expect="lower")]).iloc[0]
    assert row.method.startswith("one-sample") and row.verdict == C.REPRODUCED and row.effect < 0


def test_missing_runs_are_not_tested_and_left_out_of_holm():
    rng = np.random.default_rng(8)
    base = rng.normal(30, 0.3, 6)
    df = runs({("baseline", "studio"): base, ("cc", "studio"): base + 1 + rng.normal(0, 0.05, 6)})
    df.loc[df.variant == "cc", "status"] = ["FINISHED"] * 5 + ["FAILED"]
    out = C.evaluate(df, [claim(id="ok"), claim(id="gone", a="free_init"), claim(id="nowhere", scenes=("fast",)),
                          claim(id="nometric", metric="flicker_static")])
    assert out.n[0] == "5 pairs"  # the failed run's pair is dropped, not imputed
    assert list(out.verdict) == [C.REPRODUCED, C.NOT_TESTED, C.NOT_TESTED, C.NOT_TESTED]
    assert "free_init" in out.note[1] and "fast" in out.note[2] and "flicker_static" in out.note[3]
    assert out.p_holm[0] == pytest.approx(out.p[0])  # one tested claim: no correction


# --------------------------------------------------------------------------- schema


def _study_with(tmp_path: Path, claims: list[dict]) -> Path:
    raw = yaml.safe_load((Path(__file__).parent / "studies" / "toy.yaml").read_text())
    raw["claims"] = claims
    (tmp_path / "toy.yaml").write_text(yaml.safe_dump(raw))
    return tmp_path


GOOD = {"id": "cc_mean", "claim": "CC raises PSNR.", "metric": "psnr", "test": "mean", "a": "cc", "b": "baseline",
        "expect": "higher", "paper_number": None}


def test_claims_load_as_data(tmp_path: Path):
    study = load_study("toy", _study_with(tmp_path, [GOOD, {**GOOD, "id": "spread", "test": "variance",
                                                            "expect": "lower", "paper_number": "0.1 dB"}]))
    assert [c.id for c in study.claims] == ["cc_mean", "spread"]
    assert study.claims[0].pair == "seed" and study.claims[1].paper_number == "0.1 dB"


@pytest.mark.parametrize("change, words", [
    ({"metric": "psnr2"}, "unknown metric 'psnr2'"),
    ({"a": "nosuch"}, "unknown variant 'nosuch'"),
    ({"test": "anova"}, "unknown comparison 'anova'"),
    ({"expect": "weak"}, "not an expectation of a mean test"),
    ({"test": "interaction", "scenes": ["easy"]}, "exactly two scenes"),
    ({"colour": 1}, "unknown key(s) colour"),
])
def test_bad_claims_are_one_line_exit_2(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                        capsys: pytest.CaptureFixture[str], change: dict, words: str):
    import harness.spec.files
    from harness.cli.study import main

    root = _study_with(tmp_path, [{**GOOD, **change}])
    with pytest.raises(InputError, match=None) as err:
        load_study("toy", root)
    assert words in str(err.value)
    monkeypatch.setattr(harness.spec.files, "STUDIES_DIR", root)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        main(["report", "toy"])
    assert exc.value.code == 2
    lines = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert len(lines) == 1 and words in lines[0] and "claims" in lines[0]


def test_every_secret_states_its_claims():
    """The index needs a row for each secret, the ablation and the CC-per-scene claim."""
    tests = {name: {c.test for c in load_study(name).claims}
             for name in ("secret1", "secret2", "secret3", "secret4", "secret5", "ablation", "lpips")}
    assert all(tests.values()), tests
    assert "correlation" in tests["secret2"] and "interaction" in tests["secret3"]
    assert {"mean", "variance"} <= tests["secret5"]
    per_scene = [c for c in load_study("ablation").claims if c.scenes == ("color_shift",)]
    assert per_scene and per_scene[0].a == "flow_gate_cc" and per_scene[0].b == "flow_gate"
