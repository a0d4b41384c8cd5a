"""Did these runs reproduce a committed report? Cell by cell, bit for bit, and why not.

``compare(ours, reference)`` matches the per-run frame of a study (``report.results``) with a
committed ``runs.csv`` on (variant, scene, seed) and compares every deterministic metric
(the metric registry: timings are not) that both sides finished. Each pair is
``identical``, ``different`` (with the largest absolute difference of each metric) or
``unmatched`` (a side did not finish). For a different pair it names what differs between
the two runs' provenance: the config (``config_hash``), the trainer code
(``trainer_fingerprint``) or the determinism domain (``domain``); none of them means the
difference is unexplained, which is a finding worth an issue.

``summary(frame)`` is the verdict line ``make demo`` ends with.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from harness.analysis.aggregate import metric_columns
from harness.spec.metrics import lookup

KEY = ["variant", "scene", "seed"]
PROVENANCE = {"config_hash": "config", "trainer_fingerprint": "trainer code", "domain": "determinism domain"}


def read_reference(path: str) -> pd.DataFrame:
    """A committed ``runs.csv`` with floats read back exactly as written."""
    return pd.read_csv(path, float_precision="round_trip", keep_default_na=False, na_values=[""])


def _metrics(ours: pd.DataFrame, reference: pd.DataFrame) -> list[str]:
    common = set(metric_columns(ours)) & set(metric_columns(reference))
    return sorted(m for m in common if lookup(m).deterministic)


def _why(a: pd.Series, b: pd.Series) -> str:
    """What differs in the provenance of two runs ("" when nothing recorded differs)."""
    reasons = []
    for col, what in PROVENANCE.items():
        x, y = str(a.get(col, "") or ""), str(b.get(col, "") or "")
        if x in ("", "nan") or y in ("", "nan"):
            if col != "config_hash":
                reasons.append(f"{what} not recorded on {'this run' if x in ('', 'nan') else 'the reference'}")
        elif x != y:
            reasons.append(f"{what} ({y} in the reference, {x} here)")
    return "; ".join(reasons)


def compare(ours: pd.DataFrame, reference: pd.DataFrame) -> pd.DataFrame:
    """One row per (variant, scene, seed) of either side: ``outcome``, ``metrics_compared``,
    ``max_abs_diff`` per differing metric (text), ``psnr_diff`` and ``why``."""
    metrics = _metrics(ours, reference)
    ref = reference.assign(seed=reference.seed.astype(int)).set_index(KEY)
    mine = ours.assign(seed=ours.seed.astype(int)).set_index(KEY)
    rows = []
    for key in list(dict.fromkeys([*mine.index, *ref.index])):
        a = mine.loc[key] if key in mine.index else None
        b = ref.loc[key] if key in ref.index else None
        row = dict(zip(KEY, key), outcome="unmatched", metrics_compared=0, differing="", psnr_diff=math.nan, why="")
        if a is None or b is None or a.status != "FINISHED" or b.status != "FINISHED":
            side = "here" if a is None or a.status != "FINISHED" else "in the reference"
            row["why"] = f"not finished {side}"
            rows.append(row)
            continue
        shared = [m for m in metrics if pd.notna(a.get(m)) and pd.notna(b.get(m))]
        diffs = {m: abs(float(a[m]) - float(b[m])) for m in shared if float(a[m]) != float(b[m])}
        row.update(metrics_compared=len(shared), outcome="different" if diffs else "identical",
                   differing=", ".join(f"{m} {d:.3g}" for m, d in sorted(diffs.items())),
                   psnr_diff=float(a["psnr"]) - float(b["psnr"]) if "psnr" in shared else math.nan)
        if diffs:
            row["why"] = _why(a, b) or "unexplained: same config, code and domain"
        rows.append(row)
    return pd.DataFrame(rows)


def summary(frame: pd.DataFrame, reference: str) -> list[str]:
    """The verdict: ``25/25 runs bit-identical to the committed report (...)``, or how many
    differ, by how much and why."""
    matched = frame[frame.outcome != "unmatched"]
    same = int((matched.outcome == "identical").sum())
    lines = [f"{same}/{len(matched)} runs bit-identical to the committed report ({reference})"]
    diff = matched[matched.outcome == "different"]
    if len(diff):
        psnr = diff.psnr_diff.dropna().abs()
        size = f"; PSNR by up to {psnr.max():.4f} dB (median {np.median(psnr):.4f})" if len(psnr) else ""
        lines.append(f"{len(diff)} differ{size}")
        for why, n in diff.why.value_counts().items():
            lines.append(f"  {n} run(s): {why}")
    unmatched = frame[frame.outcome == "unmatched"]
    if len(unmatched):
        lines.append(f"{len(unmatched)} not compared: " + "; ".join(
            f"{n} {why}" for why, n in unmatched.why.value_counts().items()))
    return lines
