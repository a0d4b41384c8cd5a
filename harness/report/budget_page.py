"""The budget search in a report: ``outputs/reports/budget/<scene>/`` (budget.md, budget.csv,
budget.png) — PSNR and training time per budget tried, the decisions, the answer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from harness.analysis.budget_search import METRICS, BudgetSearch
from harness.report.plots import save_figure
from harness.spec.metrics import label


def frame(found: BudgetSearch) -> pd.DataFrame:
    """One row per budget tried: runs, mean ± std PSNR, mean train seconds, and the mean count of
    Gaussians drawn nowhere in the clip (``n_faded``: never visible, so not part of the model)."""
    def mean(values: list[float]) -> float:
        v = np.asarray(values, dtype=float)
        return float(np.nanmean(v)) if np.isfinite(v).any() else np.nan

    rows = [{"budget": b, "n": len(p), "psnr_mean": float(np.mean(p)), "psnr_std": float(np.std(p, ddof=1))
             if len(p) > 1 else np.nan, "train_seconds": mean(found.seconds[b]),
             "n_faded": mean(found.faded.get(b, []))}
            for b, p in sorted(found.scores.items())]
    return pd.DataFrame(rows)


def markdown(found: BudgetSearch, true_size: int | None = None, command: str = "") -> str:
    """The page; ``true_size``: the number of Gaussians a known-size scene is drawn from;
    ``command``: the invocation that made it (named with the code version)."""
    from harness.tracking.provenance import git_sha, trainer_fingerprint

    table = frame(found)
    lines = [f"# The smallest budget scene `{found.scene}` needs", "",
             f"Doubling from {table.budget.min()} Gaussians while doubling gains at least {found.threshold:g} dB of"
             f" {METRICS[found.metric]} (`{found.metric}`), then bisecting; each budget judged against the largest"
             " tried.", "",
             f"| Gaussians | runs | {label(found.metric)} | train time (s) | drawn nowhere in the clip |",
             "|---:|---:|---:|---:|---:|"]
    for r in table.itertuples():
        mark = " **(chosen)**" if r.budget == found.chosen else ""
        faded = "—" if np.isnan(r.n_faded) else f"{r.n_faded:,.0f} ({r.n_faded / r.budget:.0%})"
        lines.append(f"| {r.budget}{mark} | {r.n} | {r.psnr_mean:.2f} ± {r.psnr_std:.2f} | {r.train_seconds:.1f} |"
                     f" {faded} |")
    lines += ["", "Decisions:", "", *[f"- {s}" for s in found.steps], ""]
    if not found.saturated:
        lines.append(f"**No saturation:** doubling still gained {found.threshold:g} dB or more at the largest budget"
                     f" allowed; {found.chosen} is the largest tried, not a sufficient one (raise --max).")
    else:
        g = found.gap()
        settled = "settled" if g.settled_below(found.threshold) else "not settled: the interval reaches it"
        lines.append(f"**Smallest sufficient budget: {found.chosen} Gaussians**, {g.mean:.2f} dB"
                     f" [{g.low:.2f}, {g.high:.2f}] below {found.best} ({settled}); it saves"
                     f" {found.seconds_saved():.1f} s of training per run.")
    if command:
        made = ", ".join(f"`{t}`" for t in sorted(found.trainers)) or f"`{trainer_fingerprint()}`"
        trainers = "trainers" if len(found.trainers) > 1 else "trainer"
        lines += ["", f"Made by `{command}` at commit `{git_sha()}`; the runs' {trainers}: {made}."]
    if true_size:
        answer = (f"the answer is {found.chosen / true_size:.2f} times its true size" if found.saturated else
                  f"the search did not saturate by {found.chosen:,} Gaussians, {found.chosen / true_size:.2f} times its"
                  " true size")
        lines += ["", f"The scene is drawn from **K = {true_size:,} Gaussians** that FreeTimeGS can redraw one for one"
                      f" (harness/run/known_size.py): {answer}."]
    return "\n".join(lines) + "\n"


def write(found: BudgetSearch, out: Path, true_size: int | None = None, command: str = "") -> Path:
    """``budget.md``, ``budget.csv`` and ``budget.png`` under ``out``; returns the Markdown's path."""
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    table = frame(found)
    settled = found.saturated and found.chosen != found.best and found.gap().settled_below(found.threshold)
    table.assign(chosen=table.budget == found.chosen, saturated=found.saturated, settled=settled,
                 true_size=true_size or float("nan")).to_csv(out / "budget.csv", index=False)
    fig, ax = plt.subplots(figsize=(6.0, 4.0))
    ax.errorbar(table.budget, table.psnr_mean, yerr=table.psnr_std.fillna(0), marker="o", capsize=3)
    if found.chosen is not None:
        ax.plot([found.chosen], [table.set_index("budget").psnr_mean[found.chosen]], "*", ms=16, color="C3",
                label="smallest sufficient" if found.saturated else "largest tried (no saturation)")
        ax.legend(fontsize=8)
    ax.set_xscale("log", base=2)
    ax.set_xlabel("Gaussians")
    ax.set_ylabel(f"{METRICS[found.metric]} (dB)")
    ax.set_title(f"{found.scene}: {label(found.metric).removesuffix(' (dB)')} per budget (mean ± std over seeds)",
                 fontsize=10)
    ax.grid(alpha=0.3)
    if true_size:
        ax.axvline(true_size, color="grey", ls=":", label=f"true size K = {true_size:,}")
        ax.legend(fontsize=8)
    save_figure(fig, out / "budget.png")
    (out / "budget.md").write_text(markdown(found, true_size, command))
    return out / "budget.md"
