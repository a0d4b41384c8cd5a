"""Run-to-run spread split by source: optimisation, initialisation, hardware (kernel dispatch).

A study's ``variance_components:`` names the variants that isolate each source:

- ``optimisation``: initialisation fixed, the seed varies only the optimisation;
  its spread over seeds is the optimisation component.
- ``initialisation``: initialisation re-drawn per seed too; its variance minus the
  optimisation variance is the initialisation component (0 when negative).
- ``hardware``: the same seed and initialisation trained with other CPU kernel sets
  (``dispatch=``); the spread *within* each seed, pooled over seeds, is the numerical
  component: how far a number moves on another machine with everything else equal.

Standard deviations are pooled over scenes (and seeds for hardware) as the root of the
mean of within-group variances (ddof 1), with a χ² 95% interval on the pooled df.

    frame = components(df, study.variance)   # df: report.results.runs_frame output
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy import stats

from harness.spec.study_schema import VarianceSpec


def _pooled(groups: list[np.ndarray]) -> tuple[float, int, int]:
    """Pooled SD over groups (each ddof 1), its degrees of freedom, and how many values."""
    groups = [g[np.isfinite(g)] for g in groups]
    groups = [g for g in groups if len(g) >= 2]
    dof = sum(len(g) - 1 for g in groups)
    if dof == 0:
        return math.nan, 0, sum(len(g) for g in groups)
    ss = sum(((g - g.mean()) ** 2).sum() for g in groups)
    return math.sqrt(ss / dof), dof, sum(len(g) for g in groups)


def _ci(sd: float, dof: int) -> tuple[float, float]:
    if dof == 0 or not math.isfinite(sd):
        return math.nan, math.nan
    lo = sd * math.sqrt(dof / stats.chi2.ppf(0.975, dof))
    hi = sd * math.sqrt(dof / stats.chi2.ppf(0.025, dof))
    return lo, hi


def components(df: pd.DataFrame, spec: VarianceSpec) -> pd.DataFrame:
    """One row per component: sd, 95% CI, degrees of freedom, runs used, and a description."""
    m = spec.metric
    ok = df[df.status == "FINISHED"]
    ok = ok[ok[m].notna()] if m in ok else ok.iloc[0:0].assign(**{m: []})

    def per_scene(variant: str) -> list[np.ndarray]:
        sub = ok[ok.variant == variant]
        return [g[m].to_numpy(float) for _, g in sub.groupby("scene")]

    rows = []
    opt_sd, opt_dof, opt_n = _pooled(per_scene(spec.optimisation))
    rows.append(("optimisation", opt_sd, *_ci(opt_sd, opt_dof), opt_dof, opt_n,
                 f"`{spec.optimisation}` over seeds (initialisation fixed)"))
    free_sd, free_dof, free_n = _pooled(per_scene(spec.initialisation))
    rows.append(("initialisation + optimisation", free_sd, *_ci(free_sd, free_dof), free_dof, free_n,
                 f"`{spec.initialisation}` over seeds (initialisation re-drawn per seed)"))
    init_sd = math.sqrt(max(free_sd**2 - opt_sd**2, 0.0)) if math.isfinite(free_sd + opt_sd) else math.nan
    rows.append(("initialisation (share)", init_sd, math.nan, math.nan, min(free_dof, opt_dof), free_n + opt_n,
                 "sqrt(var(init + optimisation) - var(optimisation)), 0 if negative"))
    hw = ok[ok.variant.isin(spec.hardware)]
    hw_groups = [g[m].to_numpy(float) for _, g in hw.groupby(["scene", "seed"])]
    hw_sd, hw_dof, hw_n = _pooled(hw_groups)
    rows.append(("hardware (kernel dispatch)", hw_sd, *_ci(hw_sd, hw_dof), hw_dof, hw_n,
                 f"same seed and initialisation across {', '.join(f'`{v}`' for v in spec.hardware)}"))
    frame = pd.DataFrame(rows, columns=["component", "sd", "ci_low", "ci_high", "dof", "n_runs", "how"])
    spreads = [g.max() - g.min() for g in hw_groups if len(g) >= 2 and np.isfinite(g).all()]
    frame.attrs["hardware_max_range"] = max(spreads) if spreads else math.nan
    frame.attrs["metric"] = m
    return frame
