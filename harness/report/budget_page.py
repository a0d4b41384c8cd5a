"""The budget search in a report: ``outputs/reports/budget/<scene>/`` (budget.md, budget.csv,
budget.png) — per budget tried: the metric, its gap to the best with the interval, the Gaussians
the model draws (``n_alive``), its bytes and training time; the decisions; the answer."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from harness.analysis.budget_search import ALPHA, N_MAX, METRICS, BudgetSearch
from harness.report.plots import save_figure
from harness.spec.metrics import label


def _mean(values: list[float]) -> float:
    v = np.asarray(values, dtype=float)
    return float(np.nanmean(v)) if np.isfinite(v).any() else np.nan


def frame(found: BudgetSearch) -> pd.DataFrame:
    """One row per budget tried: runs, mean ± std of the metric (``psnr_mean``, ``psnr_std``), its
    gap to the best (best − budget, ``gap_low``/``gap_high`` the 90% interval), mean train seconds,
    mean Gaussians drawn nowhere in the clip (``n_faded``), drawn somewhere (``n_alive`` =
    n_gaussians − n_faded) and the model's bytes (``model_bytes``)."""
    rows = []
    for b, p in sorted(found.scores.items()):
        g = found.gap(b)
        rows.append({"budget": b, "n": len(p), "psnr_mean": float(np.mean(p)),
                     "psnr_std": float(np.std(p, ddof=1)) if len(p) > 1 else np.nan,
                     "gap_mean": g.mean, "gap_low": g.low, "gap_high": g.high,
                     "train_seconds": _mean(found.seconds[b]), "n_faded": _mean(found.faded.get(b, [])),
                     "n_alive": _mean(found.alive.get(b, [])), "model_bytes": _mean(found.model_bytes.get(b, []))})
    return pd.DataFrame(rows)


def _size(table: pd.DataFrame, budget: int) -> str:
    """``1,234 drawn, 0.29 MB`` for a budget's row (what is known of it)."""
    r = table.set_index("budget").loc[budget]
    parts = ([] if np.isnan(r.n_alive) else [f"{r.n_alive:,.0f} Gaussians drawn"]) + \
        ([] if np.isnan(r.model_bytes) else [f"{r.model_bytes / 1e6:.2f} MB"])
    return ", ".join(parts) or "size not logged"


def _needed(found: BudgetSearch) -> str:
    if found.still_gains:
        return "the last doubling still gains more than the SESOI: raise --max"
    if math.isfinite(found.runs_needed):
        return (f"settling the last doubling's equivalence needs about {found.runs_needed:.0f} runs per budget"
                " (80% power at the SD these runs show; --seeds)")
    return (f"settling it needs more than {N_MAX} runs per budget" if found.runs_needed == math.inf else
            "the runs show no spread to size more runs with")


def answer(found: BudgetSearch, true_size: int | None = None) -> str:
    """The answer in one paragraph (Markdown): the budget, its gap to the best with its interval,
    whether that is settled, what the model draws and weighs, or why there is no answer."""
    table = frame(found)
    if not found.saturated:
        text = (f"**No settled answer up to {max(found.scores):,} Gaussians:** no doubling's gain was settled"
                f" inside ±{found.sesoi:g} dB; {_needed(found)}. The best tried is {found.best:,}"
                f" ({_size(table, found.best)}).")
    else:
        g = found.gap()
        verdict = ("settled" if found.settled else f"not settled: the bound reaches {found.sesoi:g} dB")
        text = (f"**Smallest sufficient budget: {found.chosen:,} Gaussians** ({_size(table, found.chosen)}),"
                f" {g.mean:.2f} dB [{g.low:.2f}, {g.high:.2f}] below the best ({found.best:,};"
                f" {_size(table, found.best)}), {verdict}; it saves {found.seconds_saved():.1f} s of training per"
                " run.")
    if true_size:
        text += f" The scene is drawn from K = {true_size:,} Gaussians: {found.chosen / true_size:.2f} × K."
    if found.control:
        sd = np.std(found.control, ddof=1) if len(found.control) > 1 else 0.0
        text += (f" Started from the true K Gaussians (perturbed, `init.matcher=known`) the optimiser reaches"
                 f" {np.mean(found.control):.2f} ± {sd:.2f} dB at K ({len(found.control)} runs).")
    return text


def markdown(found: BudgetSearch, true_size: int | None = None, command: str = "") -> str:
    """The page; ``true_size``: the number of Gaussians a known-size scene is drawn from;
    ``command``: the invocation that made it (named with the code version)."""
    from harness.tracking.provenance import git_sha, trainer_fingerprint

    table = frame(found)
    level = f"{1 - 2 * ALPHA:.0%}"
    lines = [f"# The smallest budget scene `{found.scene}` needs", "",
             f"The fewest Gaussians whose {METRICS[found.metric]} (`{found.metric}`) is within the SESOI"
             f" ({found.sesoi:g} dB, docs/sesoi.md) of the best model trained, settled over seeds: doubling from"
             f" {table.budget.min()} until a doubling's gain lies inside ±{found.sesoi:g} dB with its {level}"
             " interval (the TOST's), then bisecting down to the smallest budget whose gap to the best has its"
             f" upper bound (one-sided 95%) below {found.sesoi:g} dB (docs/studies.md, \"The smallest model\").", "",
             f"| Gaussians | runs | {label(found.metric)} | below the best ({level}) | Gaussians drawn (n_alive) |"
             " drawn nowhere | model size (MB) | train time (s) |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in table.itertuples():
        mark = " **(chosen)**" if r.budget == found.chosen else ""
        mark += " *(best)*" if r.budget == found.best else ""
        gap = "—" if r.budget == found.best else f"{r.gap_mean:+.2f} [{r.gap_low:+.2f}, {r.gap_high:+.2f}]"
        alive = "—" if np.isnan(r.n_alive) else f"{r.n_alive:,.0f}"
        faded = "—" if np.isnan(r.n_faded) else f"{r.n_faded:,.0f} ({r.n_faded / r.budget:.0%})"
        size = "—" if np.isnan(r.model_bytes) else f"{r.model_bytes / 1e6:.2f}"
        lines.append(f"| {r.budget}{mark} | {r.n} | {r.psnr_mean:.2f} ± {r.psnr_std:.2f} | {gap} | {alive} | {faded} |"
                     f" {size} | {r.train_seconds:.1f} |")
    lines += ["", "Decisions:", "", *[f"- {s}" for s in found.steps], "", answer(found, true_size)]
    if command:
        made = ", ".join(f"`{t}`" for t in sorted(found.trainers)) or f"`{trainer_fingerprint()}`"
        trainers = "trainers" if len(found.trainers) > 1 else "trainer"
        lines += ["", f"Made by `{command}` at commit `{git_sha()}`; the runs' {trainers}: {made}."]
    if true_size:
        lines += ["", f"The scene is drawn from **K = {true_size:,} Gaussians** that FreeTimeGS can redraw one for one"
                      " (harness/run/known_size.py)."]
    return "\n".join(lines) + "\n"


def write(found: BudgetSearch, out: Path, true_size: int | None = None, command: str = "") -> Path:
    """``budget.md``, ``budget.csv`` and ``budget.png`` under ``out``; returns the Markdown's path."""
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    table = frame(found)
    control = _mean(found.control) if found.control else float("nan")
    table.assign(chosen=table.budget == found.chosen, best=table.budget == found.best, saturated=found.saturated,
                 settled=found.settled, sesoi=found.sesoi, runs_needed=found.runs_needed,
                 true_size=true_size or float("nan"), control_mean=control).to_csv(out / "budget.csv", index=False)
    fig, ax = plt.subplots(figsize=(6.0, 4.0))
    ax.errorbar(table.budget, table.psnr_mean, yerr=table.psnr_std.fillna(0), marker="o", capsize=3)
    best = table.set_index("budget").psnr_mean[found.best]
    ax.axhspan(best - found.sesoi, best, color="C2", alpha=0.15,
               label=f"within the SESOI of the best ({found.sesoi:g} dB)")
    if found.chosen is not None:
        ax.plot([found.chosen], [table.set_index("budget").psnr_mean[found.chosen]], "*", ms=16, color="C3",
                label="smallest sufficient" if found.saturated else "best tried (not settled)")
    if true_size:
        ax.axvline(true_size, color="grey", ls=":", label=f"true size K = {true_size:,}")
        if found.control:
            ax.plot([true_size], [control], "D", color="C1", label="from the true Gaussians (control)")
    ax.legend(fontsize=8)
    ax.set_xscale("log", base=2)
    ax.set_xlabel("Gaussians")
    ax.set_ylabel(f"{METRICS[found.metric]} (dB)")
    ax.set_title(f"{found.scene}: {label(found.metric).removesuffix(' (dB)')} per budget (mean ± std over seeds)",
                 fontsize=10)
    ax.grid(alpha=0.3)
    save_figure(fig, out / "budget.png")
    (out / "budget.md").write_text(markdown(found, true_size, command))
    return out / "budget.md"
