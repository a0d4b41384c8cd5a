"""Claims in a report: the "Claims" table of ``study report NAME`` (Markdown and LaTeX).

``claims_markdown`` / ``claims_latex`` render the frame ``analysis.claims.evaluate`` returns;
``correlation_plot`` draws the runs behind a correlation claim (secret 2: motion error
against PSNR over every run and variant).
"""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

from harness.analysis import claims as claims_mod
from harness.report.fmt import num, p_text, text
from harness.report.tables import decimals, latex_escape, pretty
from harness.spec.study import ClaimSpec

VERDICT_MARK = {claims_mod.REPRODUCED: "✅ reproduced", claims_mod.CONTRADICTED: "❌ contradicted",
                claims_mod.INCONCLUSIVE: "❔ inconclusive", claims_mod.NOT_TESTED: "— not tested"}


def _digits(row: pd.Series) -> int:
    return 3 if row.test == "correlation" else decimals(row.metric)


def effect_text(row: pd.Series) -> str:
    """``+0.42 [+0.31, +0.53]`` (effect and 95% CI in the metric's precision)."""
    if math.isnan(row.effect):
        return "—"
    d = _digits(row)
    return f"{num(row.effect, d, True)} [{num(row.ci_low, d, True)}, {num(row.ci_high, d, True)}]"


def needed_text(row: pd.Series) -> str:
    """Runs per arm (correlations: runs) for 80% power, for inconclusive claims only."""
    if row.verdict != claims_mod.INCONCLUSIVE or math.isnan(row.n_needed):
        return ""
    if math.isinf(row.n_needed):
        return "none (observed |r| ≥ threshold)" if row.test == "correlation" else "none (no effect observed)"
    return f"{int(row.n_needed)} runs" if row.test == "correlation" else f"{int(row.n_needed)}"


def claims_markdown(frame: pd.DataFrame) -> str:
    """The claims table: one row per claim, verdict last; footnotes say how it was tested."""
    if frame.empty:
        return "This study states no claims."
    lines = ["| Claim | Paper | Comparison (metric) | Effect [95% CI] | n | Statistic | p (Holm) | Verdict |"
             " n/arm for 80% power |", "|---|---|---|---|---|---:|---:|---|---:|"]
    for r in frame.itertuples():
        stat = f"{r.stat_name} = {r.statistic:.2f}" if not math.isnan(r.statistic) else "—"
        verdict = VERDICT_MARK[r.verdict] + (f" ({r.note})" if r.note else "")
        detail = f"; {r.detail}" if r.detail else ""
        lines.append(f"| **{r.id}**: {r.statement} | {text(r.paper_number)} | {r.comparison} (`{r.metric}`{detail}) |"
                     f" {effect_text(pd.Series(r._asdict()))} | {text(r.n)} | {stat} | {p_text(r.p_holm)} |"
                     f" {verdict} | {needed_text(pd.Series(r._asdict()))} |")
    methods = sorted({m for m in frame.method if m})
    lines += ["", f"Tests: {'; '.join(methods) or 'none run'}. p-values Holm-corrected over the"
              f" {int(frame.p.notna().sum())} claim(s) tested; α = {claims_mod.ALPHA}. Reproduced: claimed"
              " direction and significant; contradicted: opposite direction and significant; inconclusive"
              " otherwise (last column: runs per arm a two-sided test would need for 80% power at the"
              " observed effect)."]
    return "\n".join(lines)


def claims_latex(frame: pd.DataFrame, study: str) -> str:
    """A booktabs table of the claims (needs ``\\usepackage{booktabs}``)."""
    lines = [r"\begin{table}[t]", r"\centering",
             rf"\caption{{{latex_escape(study)}: the paper's claims on our runs; effect with 95\% CI,"
             r" Holm-corrected $p$.}",
             rf"\label{{tab:{study}-claims}}", r"\begin{tabular}{llllrl}", r"\toprule",
             r"Claim & Comparison & Effect [95\% CI] & $n$ & $p_\mathrm{Holm}$ & Verdict \\", r"\midrule"]
    for _, r in frame.iterrows():
        lines.append(" & ".join([latex_escape(r.id), latex_escape(r.comparison).replace("−", "$-$"),
                                 latex_escape(effect_text(r)),
                                 latex_escape(text(r.n)), latex_escape(p_text(r.p_holm)), r.verdict]) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}"]
    return "\n".join(lines)


def correlation_plot(df: pd.DataFrame, claim: ClaimSpec, r: float, path: Path) -> Path:
    """Scatter of ``claim.versus`` against ``claim.metric`` over the finished runs: colour =
    variant, marker = scene; the title gives the within-scene r the claim is tested on."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = df[(df.status == "FINISHED")]
    ok = ok[ok[claim.metric].notna() & ok[claim.versus].notna()] if {claim.metric, claim.versus} <= set(ok) else ok[:0]
    fig, ax = plt.subplots(figsize=(6.4, 4.4), constrained_layout=True)
    markers = "osD^vP*X"
    for j, scene in enumerate(dict.fromkeys(ok.scene)):
        for i, variant in enumerate(dict.fromkeys(ok.variant)):
            sub = ok[(ok.scene == scene) & (ok.variant == variant)]
            if len(sub):
                ax.scatter(sub[claim.metric], sub[claim.versus], color=f"C{i}", marker=markers[j % len(markers)],
                           label=f"{variant} / {scene}", alpha=0.8)
    ax.set_xlabel(pretty(claim.metric))
    ax.set_ylabel(pretty(claim.versus))
    ax.set_title(f"{claim.id}: every run (within-scene r = {r:+.2f}, n = {len(ok)})", fontsize=10)
    ax.grid(alpha=0.3)
    if len(ok):
        ax.legend(fontsize=7, loc="best")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
