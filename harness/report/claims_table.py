"""Claims in a report: the "Claims" table of ``study report NAME`` (Markdown and LaTeX), the
text pieces ``reports/index.md`` shares, and the scatter behind an existential claim.

``claims_markdown`` / ``claims_latex`` render the frame ``analysis.verdicts.decide`` returns;
``decoupled_plot`` draws every run of a ``decoupled`` claim (secret 2: motion error against
PSNR, per scene and variant).
"""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

from harness.analysis import stats, verdicts as V
from harness.report.fmt import num, p_text, text
from harness.report.tables import decimals, latex_escape, pretty
from harness.spec.study_schema import ClaimSpec

VERDICT_MARK = {V.REPRODUCED: "✅ reproduced", V.CONTRADICTED: "❌ contradicted", V.EQUIVALENT: "🟰 equivalent",
                V.INCONCLUSIVE: "❔ inconclusive", V.NOT_TESTED: "— not tested", V.NOT_EXERCISED: "⊘ not exercised"}
VERDICT_RULES = (
    "Verdicts: **equivalent** — the equivalence test (TOST at ±SESOI) rejects: no effect as large as the"
    " smallest effect of interest at this scale; **reproduced** / **contradicted** — the difference test"
    " rejects with the effect in the claimed / the opposite direction (a `not_higher` or `not_lower` claim is"
    " also reproduced by equivalence; an existential claim by its own test); **inconclusive** — neither, with"
    " the runs per arm 80% power at the SESOI needs; **not exercised** — the mechanism the claim needs is"
    " absent on the scene; **not tested** — the runs it needs are missing. α = 0.05 after the family's"
    " correction. A claim whose scenes disagree (scene × variant interaction significant, effects of opposite"
    " sign) is tested per scene and labelled scene-dependent.")


def _digits(row: pd.Series) -> int:
    return 2 if row.test == "variance" else decimals(row.metric)


def effect_text(row: pd.Series) -> str:
    """``+0.42 [+0.31, +0.53]``; SD ratios as ``×0.45 [×0.21, ×0.98]``."""
    if math.isnan(row.effect):
        return "—"
    d = _digits(row)
    if row.test == "variance":
        return f"×{row.effect:.{d}f} [×{row.ci_low:.{d}f}, ×{row.ci_high:.{d}f}]"
    return f"{num(row.effect, d, True)} [{num(row.ci_low, d, True)}, {num(row.ci_high, d, True)}]"


def sesoi_text(row: pd.Series) -> str:
    """``±0.34`` (``×2.75`` for SD ratios)."""
    return f"×{row.sesoi:g}" if row.test == "variance" else f"±{row.sesoi:g}"


def needed_text(row: pd.Series) -> str:
    """Runs per arm (pairs for paired tests) for 80% power at the SESOI; inconclusive rows only."""
    if row.verdict != V.INCONCLUSIVE or not isinstance(row.n_needed, float) or math.isnan(row.n_needed):
        return ""
    if math.isinf(row.n_needed):
        return f"more than {stats.N_MAX} runs/arm for 80% power at the SESOI"
    return f"≈{int(row.n_needed)} runs/arm for 80% power at the SESOI"


def verdict_text(row: pd.Series) -> str:
    scope = f" [{row.scope.split(' (')[0]}]" if str(row.scope).startswith("scene-dependent") else ""
    note = f" ({row.note})" if row.note else ""
    need = needed_text(row)
    return VERDICT_MARK[row.verdict] + (" — scene-dependent" if scope else "") + note + (f"; {need}" if need else "")


def claims_markdown(frame: pd.DataFrame) -> str:
    """The claims table: one row per hypothesis, the verdict under the study's own families."""
    if frame.empty:
        return "This study states no claims."
    lines = ["| Claim | Group | Paper | Comparison (metric) | SESOI | Effect [95% CI] | n | Statistic | p | p (family)"
             " | Verdict |", "|---|---|---|---|---:|---|---|---:|---:|---:|---|"]
    for _, r in frame.iterrows():
        stat = f"{r.stat_name} = {r.statistic:.2f}" if not math.isnan(r.statistic) else "—"
        detail = f"; {r.detail}" if r.detail else ""
        paper = text(r.paper_numbers) + (f"<br>*own evidence:* {r.paper_evidence}" if r.paper_evidence else "")
        lines.append(f"| **{r.id}**: {r.statement} | {r.group} | {paper} | {r.comparison} (`{r.metric}`{detail}) |"
                     f" {sesoi_text(r)} | {effect_text(r)} | {text(r.n)} | {stat} | {p_text(r.p)} |"
                     f" {p_text(r.p_adj)} | {verdict_text(r)} |")
    families = sorted({f for f in frame.family if f})
    methods = sorted({m for m in frame.method if m})
    sources = [f"`{r.id}`: {r.sesoi_source}" for _, r in frame.iterrows() if r.sesoi_source]
    lines += ["", f"Families (within this study only; `reports/index.md` corrects over every study's claims):"
              f" {'; '.join(families) or 'none tested'}, separately for the difference and the equivalence tests.",
              "", VERDICT_RULES, "", f"Tests: {'; '.join(methods) or 'none run'}.", "",
              "Smallest effects of interest, fixed in the study file before the runs: " + "; ".join(sources) + "."]
    return "\n".join(lines)


def claims_latex(frame: pd.DataFrame, study: str) -> str:
    """A booktabs table of the claims (needs ``\\usepackage{booktabs}``)."""
    lines = [r"\begin{table}[t]", r"\centering",
             rf"\caption{{{latex_escape(study)}: claims on our runs; effect with 95\% CI, smallest effect of"
             r" interest (SESOI), Holm-corrected $p$ within this study.}",
             rf"\label{{tab:{study}-claims}}", r"\begin{tabular}{lllrlrl}", r"\toprule",
             r"Claim & Comparison & Effect [95\% CI] & SESOI & $n$ & $p_\mathrm{Holm}$ & Verdict \\", r"\midrule"]
    for _, r in frame.iterrows():
        lines.append(" & ".join([latex_escape(r.id), latex_escape(r.comparison).replace("−", "$-$"),
                                 latex_escape(effect_text(r)), latex_escape(sesoi_text(r)),
                                 latex_escape(text(r.n)), latex_escape(p_text(r.p_adj)), r.verdict]) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}"]
    return "\n".join(lines)


def decoupled_plot(df: pd.DataFrame, claim: ClaimSpec, path: Path) -> Path:
    """Every finished run of ``claim``'s scenes: ``versus`` against ``metric``, a panel per scene,
    colour = variant. Runs in a vertical band as wide as the SESOI have equal RGB quality."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from harness.report.plots import save_figure

    ok = df[df.status == "FINISHED"]
    cols = {claim.metric, claim.versus}
    ok = ok[ok[claim.metric].notna() & ok[claim.versus].notna()] if cols <= set(ok) else ok[:0]
    scenes = list(dict.fromkeys(ok.scene)) or [""]
    fig, axes = plt.subplots(1, len(scenes), figsize=(5.0 * len(scenes), 4.2), squeeze=False, constrained_layout=True)
    for ax, scene in zip(axes[0], scenes):
        for i, variant in enumerate(dict.fromkeys(ok.variant)):
            sub = ok[(ok.scene == scene) & (ok.variant == variant)]
            if len(sub):
                ax.scatter(sub[claim.metric], sub[claim.versus], color=f"C{i}", label=variant, alpha=0.8)
        ax.set_xlabel(pretty(claim.metric))
        ax.set_ylabel(pretty(claim.versus))
        ax.set_title(scene, fontsize=10)
        ax.grid(alpha=0.3)
        if len(ok):
            ax.legend(fontsize=7, loc="best")
    fig.suptitle(f"{claim.id}: every run (equal RGB = within ±{claim.sesoi:g} of {claim.metric})", fontsize=10)
    return save_figure(fig, path)
