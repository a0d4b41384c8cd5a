"""Aggregation against a hand computation (numpy, and scipy's distributions directly)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from harness.analysis.aggregate import AVERAGE, pareto_mask, smallest_within, speed_accuracy, stability, summarize

# 2 variants x 2 scenes x 4 seeds; base/s2 seed 3 failed, cc/s1 seed 2 diverged.
PSNR = {
    ("base", "s1"): [30.0, 30.4, 29.8, 30.2],
    ("base", "s2"): [25.0, 25.5, 24.9, None],
    ("cc", "s1"): [30.9, 31.3, None, 31.0],
    ("cc", "s2"): [25.6, 26.0, 25.8, 25.7],
}


def _frame() -> pd.DataFrame:
    rows = []
    for (v, s), values in PSNR.items():
        for seed, x in enumerate(values):
            failed = x is None
            rows.append({
                "variant": v, "scene": s, "seed": seed, "config_hash": f"{v}{s}{seed}", "scene_label": s,
                "budget": 1000.0, "iterations": 100.0, "lr.scale": 1.0,
                "status": "FAILED" if failed else "FINISHED",
                "failure": ("diverged" if v == "cc" else "crashed") if failed else "",
                "error": "", "run_id": "r", "psnr": math.nan if failed else x,
            })
    return pd.DataFrame(rows)


def _welch_by_hand(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    va, vb = a.var(ddof=1) / len(a), b.var(ddof=1) / len(b)
    t = (a.mean() - b.mean()) / math.sqrt(va + vb)
    dof = (va + vb) ** 2 / (va**2 / (len(a) - 1) + vb**2 / (len(b) - 1))
    return t, 2 * stats.t.sf(abs(t), dof)


def test_mean_std_ci_and_welch_match_a_hand_computation() -> None:
    out = summarize(_frame(), "psnr", baseline="base").set_index(["variant", "scene"])
    for (v, s), values in PSNR.items():
        x = np.array([y for y in values if y is not None])
        row = out.loc[(v, s)]
        assert row.n == len(x)
        assert row["mean"] == pytest.approx(x.mean(), abs=1e-12)
        assert row["std"] == pytest.approx(math.sqrt(((x - x.mean()) ** 2).sum() / (len(x) - 1)), abs=1e-12)
        lo, hi = stats.t.interval(0.95, len(x) - 1, loc=x.mean(), scale=x.std(ddof=1) / math.sqrt(len(x)))
        assert row["ci95"] == pytest.approx((hi - lo) / 2, rel=1e-10)
        if v == "cc":
            b = np.array([y for y in PSNR[("base", s)] if y is not None])
            t, p = _welch_by_hand(x, b)
            assert row["t"] == pytest.approx(t, rel=1e-10)
            assert row["p"] == pytest.approx(p, rel=1e-8)
        else:
            assert math.isnan(row["t"])


def test_failed_and_diverged_runs_are_counted_not_dropped() -> None:
    out = summarize(_frame(), "psnr", baseline="base").set_index(["variant", "scene"])
    assert (out.loc[("base", "s2")].n_runs, out.loc[("base", "s2")].n_failed, out.loc[("base", "s2")].n_diverged) == (4, 1, 0)
    assert (out.loc[("cc", "s1")].n_failed, out.loc[("cc", "s1")].n_diverged) == (1, 1)
    assert out.loc[("cc", AVERAGE)].n_runs == 8 and out.loc[("cc", AVERAGE)].n_failed == 1


def test_average_column_is_mean_over_scenes_per_complete_seed() -> None:
    out = summarize(_frame(), "psnr", baseline="base").set_index(["variant", "scene"])
    # base: seed 3 misses s2 -> seeds 0..2 count; cc: seed 2 misses s1 -> seeds 0, 1, 3
    base = np.array([(30.0 + 25.0) / 2, (30.4 + 25.5) / 2, (29.8 + 24.9) / 2])
    cc = np.array([(30.9 + 25.6) / 2, (31.3 + 26.0) / 2, (31.0 + 25.7) / 2])
    assert out.loc[("base", AVERAGE)]["mean"] == pytest.approx(base.mean())
    assert out.loc[("cc", AVERAGE)]["std"] == pytest.approx(cc.std(ddof=1))
    assert out.loc[("cc", AVERAGE)]["p"] == pytest.approx(_welch_by_hand(cc, base)[1], rel=1e-8)


def test_pareto_front_and_smallest_budget_within_a_tenth_of_a_db() -> None:
    cost = np.array([1.0, 2.0, 3.0, 2.5])
    quality = np.array([20.0, 25.0, 25.05, 24.0])
    assert pareto_mask(cost, quality).tolist() == [True, True, True, False]
    sa = pd.DataFrame({"variant": list("abcd"), "budget": [1e3, 2e3, 5e3, 2e3], "iterations": [1e3, 1e3, 1e3, 3e3],
                       "mean": [20.0, 25.0, 25.05, 25.06], "train_seconds": [1.0, 2.0, 3.0, 5.0]})
    assert smallest_within(sa, 0.1)["variant"] == "b"  # 25.0 >= 25.06 - 0.1, smallest budget, fewer iterations
    assert smallest_within(sa, 0.01)["variant"] == "d"  # c and d qualify; d has the smaller budget


def test_speed_accuracy_and_stability_tables() -> None:
    df = _frame()
    df["train_seconds"] = 2.0
    df["n_gaussians"] = 1000.0
    sa = speed_accuracy(df).set_index("variant")
    assert sa.loc["cc", "n"] == 7 and sa.loc["cc", "n_failed"] == 1
    st = stability(df).set_index(["variant", "scene"])
    assert st.loc[("cc", "s1"), "failure_rate"] == pytest.approx(0.25)
    assert st.loc[("cc", "s1"), "n_diverged"] == 1
    assert st.loc[("base", "s1"), "spread"] == pytest.approx(30.4 - 29.8)


def test_convention_gaps_are_paired_per_run_differences() -> None:
    from harness.spec.metrics import add_differences as convention_gaps

    runs = pd.DataFrame({"variant": ["baseline"] * 3, "scene": ["s"] * 3, "seed": [0, 1, 2],
                         "status": ["FINISHED"] * 3, "failure": [""] * 3,
                         "lpips_alex": [0.10, 0.20, 0.30], "lpips_alex_01": [0.08, 0.19, 0.25],
                         "ssim1": [0.80, 0.85, 0.90], "ssim2": [0.86, 0.90, 0.93]})
    gaps = convention_gaps(runs)
    np.testing.assert_allclose(gaps["gap_lpips_alex"], [-0.02, -0.01, -0.05])
    np.testing.assert_allclose(gaps["gap_ssim"], [0.06, 0.05, 0.03])
    assert "gap_lpips_vgg" not in gaps  # only pairs whose two metrics exist
    row = summarize(gaps, "gap_lpips_alex", "baseline").query("scene == 's'").iloc[0]
    assert row["mean"] == pytest.approx(np.mean([-0.02, -0.01, -0.05]))
    assert row["std"] == pytest.approx(np.std([-0.02, -0.01, -0.05], ddof=1))
