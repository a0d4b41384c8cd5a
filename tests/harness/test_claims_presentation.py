"""What the pages show a referee: the interval each verdict used (Holm-adjusted), the forest plot
that draws it, what an interval wholly beyond the SESOI says, the exploratory mark, the index's
opening table of statements, and the runs-needed search (no solver that stops early)."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from claimdata import claim, runs
from scipy import stats
from test_claims_report import REGISTER, frame

from harness.analysis import stats as S, verdicts as V
from harness.report.claims_table import claims_latex, claims_markdown, verdict_text
from harness.report.forest import disagreements, forest_plot
from harness.report.index import StudyClaims, decide_all, index_markdown

ALPHA = 0.05
ROOT = Path(__file__).resolve().parents[2]


def holm_by_hand(p: np.ndarray) -> tuple[dict[int, float], float]:
    """Holm's step-down procedure as the textbook writes it: {index: α of the step that rejected
    it}, and the α of the step where it stopped (NaN when it never stopped)."""
    finite = [i for i in np.argsort(p, kind="stable") if np.isfinite(p[i])]
    m, rejected = len(finite), {}
    for step, i in enumerate(finite, start=1):
        level = ALPHA / (m - step + 1)
        if not p[i] < level:
            return rejected, level
        rejected[i] = level
    return rejected, math.nan


def test_holm_levels_are_the_steps_of_the_textbook_procedure():
    rng = np.random.default_rng(3)
    for _ in range(300):
        m = int(rng.integers(2, 12))
        p = np.where(rng.random(2 * m) < 0.5, rng.uniform(0, 0.02, 2 * m), rng.uniform(0, 1, 2 * m))
        p[rng.random(2 * m) < 0.15] = np.nan  # untested hypotheses are not in the family
        level_d, level_e, stop = S.holm_levels(p[:m], p[m:])
        rejected, stopped = holm_by_hand(p)
        got = np.concatenate([level_d, level_e])
        assert {i: pytest.approx(v) for i, v in rejected.items()} == {i: v for i, v in enumerate(got)
                                                                      if np.isfinite(v)}
        assert (math.isnan(stop) and math.isnan(stopped)) or stop == pytest.approx(stopped)


def _family(seed: int) -> tuple[pd.DataFrame, list]:
    """A family of paired, Welch and "≈" claims with effects from none to well past the SESOI."""
    rng = np.random.default_rng(seed)
    base = 30 + rng.normal(0, 0.3, 6)
    values, claims = {("baseline", "s"): base}, []
    for k in range(10):
        effect = float(rng.choice([-0.6, 0.0, 0.05, 0.3, 0.6]))
        values[(f"v{k}", "s")] = base + effect + rng.normal(0, float(rng.choice([0.03, 0.15])), 6)
        expect = str(rng.choice(["higher", "lower", "not_higher", "equivalent"]))
        claims.append(claim(id=f"c{k}", a=f"v{k}", sesoi=0.2, expect=expect, scenes=("s",),
                            pair="none" if k % 3 == 0 else "seed"))
    return runs(values), claims


def _oracle_interval(df: pd.DataFrame, c, level: float) -> tuple[float, float]:
    """scipy's own interval for the claim's t-test at ``level``."""
    a = df[df.variant == c.a].sort_values("seed").psnr.to_numpy()
    b = df[df.variant == c.b].sort_values("seed").psnr.to_numpy()
    res = stats.ttest_1samp(a - b, 0.0) if c.pair == "seed" else stats.ttest_ind(a, b, equal_var=False)
    ci = res.confidence_interval(level)
    return float(ci.low), float(ci.high)


def test_the_adjusted_interval_excludes_0_exactly_when_the_verdict_rejects():
    """30 simulated families of 10 claims: each counted row's interval is scipy's for its test at
    the level of the Holm step that decided it; it excludes 0 (a "≈" claim: lies outside ±SESOI)
    exactly when the difference test rejects and lies inside ±SESOI exactly when equivalence does."""
    seen = set()
    for seed in range(30):
        df, claims = _family(seed)
        out = V.decide(V.evaluate(df, claims))
        m = len(out)
        rejected, stop = holm_by_hand(np.concatenate([out.p.to_numpy(float), out.p_tost.to_numpy(float)]))
        assert disagreements(out) == []
        for j, r in out.iterrows():
            c = next(c for c in claims if c.id == r.id)
            by_equivalence = V.by_equivalence(r)
            if by_equivalence:
                level = 1 - 2 * rejected[m + j]
            elif r.verdict in (V.REPRODUCED, V.CONTRADICTED):
                level = 1 - rejected[j]
            else:
                level = 1 - stop
            assert r.ci_adj_level == pytest.approx(level)
            low, high = _oracle_interval(df, c, level)
            assert (r.ci_adj_low, r.ci_adj_high) == (pytest.approx(low), pytest.approx(high))
            inside = -c.sesoi <= low and high <= c.sesoi
            away = (low > c.sesoi or high < -c.sesoi) if c.expect == "equivalent" else (low > 0 or high < 0)
            if by_equivalence:  # TOST's interval (its difference may reject too: a small, clear effect)
                assert inside
            elif r.verdict in (V.REPRODUCED, V.CONTRADICTED):
                assert away
            else:  # nothing rejected: the interval at the level where Holm stopped shows neither
                assert not inside and not away
            seen.add((r.verdict, by_equivalence))
    # every kind of decision happened
    assert {(V.REPRODUCED, False), (V.REPRODUCED, True), (V.CONTRADICTED, False), (V.EQUIVALENT, True),
            (V.INCONCLUSIVE, False)} <= seen


def test_the_forest_plot_draws_the_intervals_claims_csv_holds(tmp_path: Path):
    f = frame().assign(study="secret5")
    f.to_csv(tmp_path / "claims.csv", index=False)
    written = pd.read_csv(tmp_path / "claims.csv")
    forest = forest_plot(written, tmp_path / "forest.png")
    drawn = forest.drawn.set_index("id")
    shown = written[written.verdict.isin([V.REPRODUCED, V.INCONCLUSIVE])].set_index("id")
    assert list(drawn.index) == list(shown.index) == ["cc_mean", "free"]
    for cid, r in shown.iterrows():  # "higher" claims: SESOI units, not mirrored
        assert drawn.loc[cid, "low"] == pytest.approx(r.ci_adj_low / r.sesoi)
        assert drawn.loc[cid, "high"] == pytest.approx(r.ci_adj_high / r.sesoi)
        assert drawn.loc[cid, "level"] == pytest.approx(r.ci_adj_level) and r.ci_adj_level > 0.95
        assert r.ci_adj_high - r.ci_adj_low > r.ci_high - r.ci_low  # wider than the 95% CI it replaces


def _row(**kw: object) -> pd.Series:
    base = {"test": "mean", "expect": "higher", "sesoi": 0.2, "effect": -0.7, "ci_low": -0.8, "ci_high": -0.6,
            "ci_adj_low": -0.9, "ci_adj_high": -0.5, "ci_adj_level": 0.999, "verdict": V.INCONCLUSIVE, "scope": "s",
            "note": "", "n_needed": math.nan, "family_size": 20.0, "raw_verdict": "", "counted": True,
            "registered_before_runs": "yes", "interval_note": ""}
    return pd.Series({**base, **kw})


def test_an_interval_wholly_beyond_the_sesoi_is_said_even_when_inconclusive():
    assert V.interval_note(_row()) == "the whole adjusted interval lies below −SESOI (the opposite direction)"
    assert V.interval_note(_row(expect="lower")) == \
        "the whole adjusted interval lies below −SESOI (the claimed direction)"
    assert V.interval_note(_row(ci_adj_low=0.3, ci_adj_high=0.5)) == \
        "the whole adjusted interval lies above +SESOI (the claimed direction)"
    assert V.interval_note(_row(ci_adj_low=-0.3, ci_adj_high=0.5)) == ""  # it reaches into the band
    assert V.interval_note(_row(expect="equivalent", ci_adj_low=0.3, ci_adj_high=0.5)) == \
        "the whole adjusted interval lies above +SESOI (against the claim)"
    ratio = _row(test="variance", sesoi=1.5, effect=2.5, ci_adj_low=1.8, ci_adj_high=4.0, expect="lower")
    assert V.interval_note(ratio) == "the whole adjusted interval lies above SESOI (the opposite direction)"
    row = _row(interval_note=V.interval_note(_row()))
    assert verdict_text(row).startswith(
        "❔ inconclusive; the whole adjusted interval lies below −SESOI (the opposite direction)")
    # decided on runs: an effect far past the SESOI says so beside "reproduced"
    rng = np.random.default_rng(1)
    base = 30 + rng.normal(0, 0.3, 8)
    out = V.decide(V.evaluate(runs({("baseline", "s"): base, ("cc", "s"): base + 1.0 + rng.normal(0, 0.05, 8)}),
                              [claim(sesoi=0.2)]))
    assert out.verdict[0] == V.REPRODUCED
    assert out.interval_note[0] == "the whole adjusted interval lies above +SESOI (the claimed direction)"


def test_a_decided_row_registered_after_its_runs_is_exploratory_on_every_page():
    f = frame()
    f.loc[f.id == "cc_mean", "registered_before_runs"] = "no"
    f.loc[f.id == "cc_mean", "registration_note"] = "its claim at abc came after its first run's commit def"
    f = V.decide(f)  # decided again: the counted row is named exploratory
    assert f.set_index("id").exploratory.to_dict() == {"cc_mean": True, "free": False, "gone": False}
    row = f.set_index("id").loc["cc_mean"]
    assert verdict_text(row).startswith("✅ reproduced") and verdict_text(row).endswith(" — exploratory ⚑")
    assert verdict_text(f.set_index("id").loc["free"]).count("⚑") == 0
    md = claims_markdown(f)
    assert "exploratory ⚑: its claim at abc came after its first run's commit def" in md
    assert "reproduced (exploratory)" in claims_latex(f, "secret5")
    entries = decide_all([StudyClaims("secret5", "q", f, "secret5/index.md", 18, "abc123")])
    page = index_markdown(entries, [], [], register=REGISTER)
    assert "4 statements: 1 reproduced, 1 inconclusive, 2 not tested (1 of them exploratory ⚑" in page
    glance = next(line for line in page.splitlines() if line.startswith("| **s_cc**"))
    assert "✅ reproduced — exploratory ⚑" in glance
    assert "1 of the 2 counted rows" not in page and "after them (exploratory ⚑): 1" in page


def test_the_index_opens_with_one_line_per_statement():
    entries = decide_all([StudyClaims("secret5", "q", frame(), "secret5/index.md", 18, "abc123")])
    page = index_markdown(entries, [], [], register=REGISTER)
    glance = [line for line in page.splitlines() if line.startswith("| **s_")]
    assert [line.split("**")[1] for line in glance] == ["s_cc", "s_free", "s_gone", "s_real"]
    assert page.index("## The paper's 4 statements at a glance") < page.index("## Families") < page.index("| secret 5 |")
    first = glance[0].split(" | ")
    row = entries[0].frame.set_index("id").loc["cc_mean"]
    assert first[1] == "DyNeRF +0.34"  # the paper's number
    assert f"{row.effect:+.2f} [{row.ci_adj_low:+.2f}, {row.ci_adj_high:+.2f}] at {100 * row.ci_adj_level:.4g}%" \
        in first[2]
    assert first[3] == "✅ reproduced" and first[4].startswith("the difference test rejects (Holm p = ")
    assert "no test rejects at the family's α" in glance[1]
    assert glance[3].endswith("| — not tested | needs real data (REAL_ROOT) |")


def test_nothing_in_the_harness_calls_a_power_solver_that_can_stop_early():
    """statsmodels' solve_power root-finds over a continuous n and stopped early (stats.n_for_t);
    every runs-needed figure comes from the integer search."""
    calls = [f"{path.relative_to(ROOT)}:{node.lineno}" for path in sorted((ROOT / "harness").rglob("*.py"))
             for node in ast.walk(ast.parse(path.read_text()))
             if isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", "")) in
             {"solve_power", "tt_solve_power", "tt_ind_solve_power"}]
    assert calls == []
