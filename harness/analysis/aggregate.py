"""Runs -> pandas DataFrame -> per variant and scene mean +- std, 95% CI, Welch t-test.

The per-run frame (``report.results.runs_frame``: one row per planned run, missing runs
included with status MISSING) has the columns named here; ``summarize`` groups the FINISHED runs of each (variant, scene) and adds an ``average``
scene: for every seed the mean over scenes (seeds missing a scene are left out), then
mean +- std over seeds. Failed, diverged and missing runs are counted in every cell,
never silently dropped. The t-test is Welch's (``scipy.stats.ttest_ind``,
``equal_var=False``) of each variant against the baseline in the same scene.
"""

from __future__ import annotations

import fnmatch
import math

import numpy as np
import pandas as pd
from scipy import stats

AVERAGE = "average"
KEY_COLUMNS = ["variant", "scene", "seed", "config_hash"]
# model_digest: a sha256 of the trained model's parameters (harness/run/training.py), where recorded
# git_sha / start_time: the commit a run was made from and when it started (spec.registration)
RUN_COLUMNS = ("scene_label", "status", "failure", "error", "run_id", "trainer_fingerprint", "model_digest", "git_sha",
               "start_time", "command")
EXTRA_PARAMS = ("budget", "iterations", "lr.scale")
INSTANCE_COLUMNS = ("instance_of", "instance")  # the scene instance a run is on (spec.instances)
# run tags that say which determinism domain a run's bits come from (ftgspp/runtime/determinism.py)
DOMAIN_COLUMNS = {"domain": "determinism.id", "determinism": "determinism.mode",
                  "cpu_capability": "determinism.torch_cpu_capability", "cpu_model": "determinism.cpu_model",
                  "torch_threads": "determinism.torch_threads"}


def match_metrics(patterns: list[str] | tuple[str, ...], available: list[str]) -> list[str]:
    """Metric names matching ``patterns`` (fnmatch), in pattern order, each once."""
    out: list[str] = []
    for pat in patterns:
        for name in sorted(available):
            if fnmatch.fnmatch(name, pat) and name not in out:
                out.append(name)
    return out


def metric_columns(df: pd.DataFrame) -> list[str]:
    """Columns that hold metrics (everything that is not a key, status or param column)."""
    fixed = {*KEY_COLUMNS, *RUN_COLUMNS, *EXTRA_PARAMS, *DOMAIN_COLUMNS, *INSTANCE_COLUMNS}
    return [c for c in df.columns if c not in fixed]


def _stats(values: np.ndarray) -> tuple[float, float, float]:
    n = len(values)
    if n == 0:
        return math.nan, math.nan, math.nan
    mean = float(values.mean())
    if n == 1:
        return mean, math.nan, math.nan
    std = float(values.std(ddof=1))
    ci = float(stats.t.ppf(0.975, n - 1) * std / math.sqrt(n))
    return mean, std, ci


def _welch(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    if len(a) < 2 or len(b) < 2 or (a.std() == 0 and b.std() == 0):
        return math.nan, math.nan
    res = stats.ttest_ind(a, b, equal_var=False)
    return float(res.statistic), float(res.pvalue)


def _per_seed_average(df: pd.DataFrame, metric: str, n_scenes: int) -> pd.Series:
    ok = df[(df.status == "FINISHED") & df[metric].notna()]
    g = ok.groupby("seed")[metric]
    means = g.mean()
    return means[g.count() == n_scenes]


def counts(sub: pd.DataFrame) -> dict[str, int]:
    return {
        "n_runs": len(sub),
        "n_finished": int((sub.status == "FINISHED").sum()),
        "n_failed": int(sub.status.isin(["FAILED", "KILLED"]).sum()),
        "n_diverged": int((sub.failure == "diverged").sum()),
        "n_running": int((sub.status == "RUNNING").sum()),
        "n_missing": int((sub.status == "MISSING").sum()),
    }


def summarize(df: pd.DataFrame, metric: str, baseline: str) -> pd.DataFrame:
    """Per (variant, scene) and (variant, ``average``): counts, mean, std, ci95, Welch t and p.

    ``metric`` values of runs that did not finish are ignored; the counts say how many.
    """
    if metric not in df.columns:
        df = df.assign(**{metric: math.nan})
    variants = list(dict.fromkeys(df.variant))
    scenes = list(dict.fromkeys(df.scene))
    rows = []
    samples: dict[tuple[str, str], np.ndarray] = {}
    for v in variants:
        for s in [*scenes, AVERAGE]:
            sub = df[df.variant == v] if s == AVERAGE else df[(df.variant == v) & (df.scene == s)]
            if s == AVERAGE:
                values = _per_seed_average(sub, metric, len(scenes)).to_numpy(dtype=float)
            else:
                ok = sub[(sub.status == "FINISHED") & sub[metric].notna()]
                values = ok[metric].to_numpy(dtype=float)
            samples[(v, s)] = values
            mean, std, ci = _stats(values)
            rows.append({"variant": v, "scene": s, "metric": metric, "n": len(values), **counts(sub),
                         "mean": mean, "std": std, "ci95": ci})
    out = pd.DataFrame(rows)
    tp = [
        _welch(samples[(r.variant, r.scene)], samples[(baseline, r.scene)])
        if r.variant != baseline and (baseline, r.scene) in samples
        else (math.nan, math.nan)
        for r in out.itertuples()
    ]
    out["t"] = [t for t, _ in tp]
    out["p"] = [p for _, p in tp]
    return out


def failures(df: pd.DataFrame) -> pd.DataFrame:
    """Rows of runs that did not finish (failed, diverged, killed, running or missing)."""
    cols = ["variant", "scene", "seed", "status", "failure", "error", "run_id"]
    return df[df.status != "FINISHED"][cols].reset_index(drop=True)


# --- speed versus accuracy and stability -------------------------------------------------


def pareto_mask(cost: np.ndarray, quality: np.ndarray) -> np.ndarray:
    """True for points no other point beats (cost <= and quality >=, one strictly)."""
    n = len(cost)
    mask = np.ones(n, dtype=bool)
    for i in range(n):
        better = (cost <= cost[i]) & (quality >= quality[i]) & ((cost < cost[i]) | (quality > quality[i]))
        mask[i] = not better.any()
    return mask


def speed_accuracy(df: pd.DataFrame, metric: str = "psnr") -> pd.DataFrame:
    """Per variant: budget, iterations, mean/std ``metric``, mean train time and #Gaussians, Pareto flags.

    Means are over every finished run of the variant (all scenes and seeds).
    """
    ok = df[df.status == "FINISHED"]
    rows = []
    for v in dict.fromkeys(df.variant):
        sub = ok[ok.variant == v]
        all_v = df[df.variant == v]
        has_n = "n_gaussians" in sub and sub["n_gaussians"].notna().any()
        n_gauss = sub["n_gaussians"].mean() if has_n else all_v["budget"].mean()
        rows.append({
            "variant": v,
            "budget": float(all_v["budget"].iloc[0]),
            "iterations": float(all_v["iterations"].iloc[0]),
            "n": len(sub),
            "n_failed": int((all_v.status != "FINISHED").sum()),
            "mean": float(sub[metric].mean()) if metric in sub and len(sub) else math.nan,
            "std": float(sub[metric].std(ddof=1)) if metric in sub and len(sub) > 1 else math.nan,
            "train_seconds": float(sub["train_seconds"].mean()) if "train_seconds" in sub and len(sub) else math.nan,
            "n_gaussians": float(n_gauss),
        })
    out = pd.DataFrame(rows)
    valid = out["mean"].notna() & out["train_seconds"].notna()
    out["pareto_time"] = False
    out["pareto_gaussians"] = False
    if valid.any():
        v = out[valid]
        out.loc[valid, "pareto_time"] = pareto_mask(v.train_seconds.to_numpy(), v["mean"].to_numpy())
        out.loc[valid, "pareto_gaussians"] = pareto_mask(v.n_gaussians.to_numpy(), v["mean"].to_numpy())
    return out


def smallest_within(sa: pd.DataFrame, tol_db: float | None = None) -> pd.Series | None:
    """The variant with the smallest budget whose mean is within ``tol_db`` (default: PSNR's
    smallest effect of interest, ``size_tolerance``) of the best (ties: fewer iterations, then
    less train time)."""
    tol_db = size_tolerance() if tol_db is None else tol_db
    ok = sa[sa["mean"].notna()]
    if ok.empty:
        return None
    best = ok["mean"].max()
    near = ok[ok["mean"] >= best - tol_db]
    return near.sort_values(["budget", "iterations", "train_seconds"]).iloc[0]


def size_tolerance(metric: str = "psnr") -> float:
    """How close to the best a model must be to count as enough: the metric's smallest effect of
    interest (docs/sesoi.md; 0.2 dB for PSNR), the same rule as ``study budget``'s finder."""
    from harness.spec.metrics import sesoi

    return sesoi(metric)[0]


def stability(df: pd.DataFrame, metric: str = "psnr") -> pd.DataFrame:
    """Per (variant, scene) cell: mean, std, spread (max - min) of finished runs and failure rate."""
    rows = []
    for (v, s), sub in df.groupby(["variant", "scene"], sort=False):
        vals = np.array([])
        if metric in sub:
            vals = sub.loc[sub.status == "FINISHED", metric].dropna().to_numpy(dtype=float)
        attempted = sub[sub.status.isin(["FINISHED", "FAILED", "KILLED"])]
        rows.append({
            "variant": v,
            "scene": s,
            "scene_label": sub.scene_label.iloc[0],
            "n": len(vals),
            "mean": float(vals.mean()) if len(vals) else math.nan,
            "std": float(vals.std(ddof=1)) if len(vals) > 1 else math.nan,
            "spread": float(vals.max() - vals.min()) if len(vals) else math.nan,
            "failure_rate": float((attempted.status != "FINISHED").mean()) if len(attempted) else math.nan,
            "n_diverged": int((sub.failure == "diverged").sum()),
        })
    out = pd.DataFrame(rows)
    out.attrs["metric"] = metric
    return out


KERNEL_SETS = {"DEFAULT": "x86-64 baseline (no AVX)", "AVX2": "AVX2", "AVX512": "AVX-512"}


def kernel_set(capability: str) -> str:
    """torch's CPU capability as people name it (``DEFAULT`` is the baseline kernel set, not the
    determinism mode of the same name)."""
    return KERNEL_SETS.get(str(capability), str(capability))


def domains(df: pd.DataFrame) -> pd.DataFrame:
    """The determinism domains of the finished runs: one row per domain with its runs and cells,
    and ``mixed_cells``: (variant, scene) cells whose runs come from more than one domain."""
    cols = ["domain", "mode", "cpu_capability", "cpu_model", "torch_threads", "runs", "variants"]
    if "domain" not in df:
        out = pd.DataFrame(columns=cols)
        out.attrs["mixed_cells"] = []
        return out
    ok = df[(df.status == "FINISHED") & (df.domain.fillna("") != "")]
    rows = []
    for dom, g in ok.groupby("domain"):
        first = g.iloc[0]
        rows.append({"domain": dom, "mode": first.determinism, "cpu_capability": first.cpu_capability,
                     "cpu_model": first.cpu_model, "torch_threads": first.torch_threads, "runs": len(g),
                     "variants": ", ".join(sorted(g.variant.unique()))})
    out = pd.DataFrame(rows, columns=cols)
    per_cell = ok.groupby(["variant", "scene"]).domain.nunique() if len(ok) else pd.Series(dtype=int)
    out.attrs["mixed_cells"] = [f"{v}/{s}" for (v, s), n in per_cell.items() if n > 1]
    return out
