"""Variance components on constructed runs where every answer is known."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from harness.analysis.variance import components
from harness.report.sections import components_markdown
from harness.spec.study_schema import VarianceSpec

SPEC = VarianceSpec("psnr", "fixed", "free", ("hw_a", "hw_b", "hw_c"))


def frame(rows):
    return pd.DataFrame([dict(status="FINISHED", scene=s, seed=seed, variant=v, psnr=x) for v, s, seed, x in rows])


def test_components_match_hand_computed_values():
    rng = np.random.default_rng(0)
    fixed = [28.0, 28.2, 27.9, 28.1, 28.3]  # var = 0.025
    free = [27.5, 28.6, 27.7, 28.9, 28.3]
    rows = [("fixed", "studio", i, x) for i, x in enumerate(fixed)] + [("free", "studio", i, x) for i, x in enumerate(free)]
    hw = {}
    for seed in range(4):  # the same seed across three dispatches: offsets (0, +0.01, -0.02)
        base = 28 + rng.normal()
        hw[seed] = [base, base + 0.01, base - 0.02]
        rows += [(v, "studio", seed, x) for v, x in zip(SPEC.hardware, hw[seed])]
    rows.append(("fixed", "studio", 9, float("nan")))  # a NaN metric is ignored
    out = components(frame(rows), SPEC).set_index("component")
    assert out.loc["optimisation", "sd"] == pytest.approx(np.std(fixed, ddof=1))
    assert out.loc["initialisation + optimisation", "sd"] == pytest.approx(np.std(free, ddof=1))
    share = math.sqrt(np.var(free, ddof=1) - np.var(fixed, ddof=1))
    assert out.loc["initialisation (share)", "sd"] == pytest.approx(share)
    pooled = math.sqrt(np.mean([np.var(v, ddof=1) for v in hw.values()]))
    assert out.loc["hardware (kernel dispatch)", "sd"] == pytest.approx(pooled)  # seeds' offsets cancel
    assert out.loc["hardware (kernel dispatch)", "dof"] == 8
    lo, hi = out.loc["optimisation", ["ci_low", "ci_high"]]
    assert lo < out.loc["optimisation", "sd"] < hi
    md = components_markdown(components(frame(rows), SPEC))
    assert "| hardware (kernel dispatch) |" in md and "0.0300" in md  # largest range: +0.01 .. -0.02


def test_missing_variants_give_nan_not_an_error():
    out = components(frame([("fixed", "s", 0, 28.0)]), SPEC)
    assert out.sd.isna().all()
