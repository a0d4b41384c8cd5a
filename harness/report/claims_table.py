"""Claims in a report: the "Claims" table of ``study report NAME`` (Markdown and LaTeX), the
text pieces ``reports/index.md`` shares, and the scatter behind an existential claim.

``claims_markdown`` / ``claims_latex`` render a study's rows of the decision over every study
(``report.families``), each with the p that decided it; ``decoupled_plot`` draws every run of a
``decoupled`` or ``dissociated`` claim (secret 2: motion error against PSNR, per scene and
variant).
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
                V.INCONCLUSIVE: "❔ inconclusive", V.NOT_TESTED: "— not tested", V.NOT_EXERCISED: "⊘ not exercised",
                V.DESCRIBED: "📏 described", V.EVIDENCE: "· evidence", V.WITHDRAWN: "↩ withdrawn"}
POST_HOC = "⚑"  # a claim not registered before its runs (computed from git: spec.registration)
EXPLORATORY = "exploratory"  # a decided row whose claim was not registered before its runs
VERDICT_RULES = (
    "Verdicts: **equivalent** — the equivalence test (TOST at ±SESOI) rejects: no effect as large as the"
    " smallest effect of interest at this scale; **reproduced** / **contradicted** — the difference test"
    " rejects with the effect in the claimed / the opposite direction (a `not_higher` or `not_lower` claim is"
    " also reproduced by equivalence; an existential claim by its own test; an \"≈\" claim is reproduced by"
    " equivalence and contradicted when the minimal-effect test puts the effect outside ±SESOI);"
    " **inconclusive** — neither, with the runs per arm that 80% power at the SESOI needs at the α the claim"
    " faces (α/m of its family); **not exercised** — the mechanism the claim needs is absent on the scene;"
    " **not tested** — the runs it needs are missing; **described** — a spread described beside the paper's,"
    " no test. α = 0.05 after one Holm correction over everything the family can reject (difference and"
    " equivalence tests together). Rows marked **evidence** (another condition of a statement) and"
    " **withdrawn** are in no family: their verdict in brackets is at the unadjusted α. A claim whose scenes"
    " disagree (scene × variant interaction significant, effects of opposite sign) is tested per scene and"
    " labelled scene-dependent. " + POST_HOC + " marks a claim not registered before its runs: git shows that"
    " the claim (its text, test, arms and scenes and their definitions) or its place in the paper register"
    " last changed in a commit that is not an ancestor of its first run's commit, or not yet committed; a"
    " decided row so marked is **exploratory** (it keeps its verdict and its place in the family).")


def _digits(row: pd.Series) -> int:
    return 2 if row.test == "variance" else decimals(row.metric)


def effect_text(row: pd.Series) -> str:
    """``+0.42 [+0.31, +0.53]``; SD ratios as ``×0.45 [×0.21, ×0.98]``; a described SD as ``SD 0.15 [0.10, 0.27]``."""
    if math.isnan(row.effect):
        return "—"
    d = _digits(row)
    if row.test == "variance":
        return f"×{row.effect:.{d}f} [×{row.ci_low:.{d}f}, ×{row.ci_high:.{d}f}]"
    if row.test == "spread":
        return f"SD {num(row.effect, d)} [{num(row.ci_low, d)}, {num(row.ci_high, d)}]"
    return f"{num(row.effect, d, True)} [{num(row.ci_low, d, True)}, {num(row.ci_high, d, True)}]"


def sesoi_text(row: pd.Series) -> str:
    """``±0.2`` (``×1.5`` for SD ratios, ``—`` for a description)."""
    if row.test == "spread":
        return "—"
    return f"×{row.sesoi:g}" if row.test == "variance" else f"±{row.sesoi:g}"


def needed_text(row: pd.Series) -> str:
    """Runs per arm (pairs for paired tests) for 80% power at the SESOI and the claim's α; inconclusive rows only."""
    if row.verdict != V.INCONCLUSIVE or not isinstance(row.n_needed, float) or math.isnan(row.n_needed):
        return ""
    alpha = row.get("alpha", stats.ALPHA)
    a = "α" if not isinstance(alpha, float) or math.isnan(alpha) or alpha >= stats.ALPHA else f"{alpha:.3g}"
    sds = (" and the pairs searched, both tests; the SDs of these runs" if row.get("power_test") == "iu"
           else ", the SD of these runs")  # "iu": an existential dissociation, Bonferroni over its pairs
    at = (f"{a}/{int(row.family_size)}" if isinstance(row.family_size, float) and row.family_size > 1 else a) + sds
    unit = "instances/arm" if "instance" in str(row.get("n", "")) else "runs/arm"  # the claim's unit (spec.instances)
    if math.isinf(row.n_needed):
        return f"more than {stats.N_MAX} {unit} for 80% power at the SESOI ({at})"
    return f"≈{int(row.n_needed)} {unit} for 80% power at the SESOI ({at})"


def deciding_p(row: pd.Series) -> float:
    """The family-corrected p that decided the row: the equivalence test's for an equivalent (or an
    equivalence-reproduced) row, else the difference test's."""
    return float(row.p_tost_adj if V.by_equivalence(row) else row.p_adj)


def late(row: pd.Series) -> bool:
    """Was the row's claim registered after its runs (the computed ``registered_before_runs``)?"""
    return row.get("registered_before_runs", "") == "no"


def exploratory(row: pd.Series) -> bool:
    """A decided (counted) row whose claim was registered after its runs."""
    return late(row) and row.verdict in V.DECIDED and bool(row.get("counted", False))


def mark_text(row: pd.Series) -> str:
    """`` — exploratory ⚑`` for an exploratory row, `` ⚑`` for another row registered after its runs."""
    return f" — {EXPLORATORY} {POST_HOC}" if exploratory(row) else f" {POST_HOC}" if late(row) else ""


def p_decided_text(row: pd.Series) -> str:
    """``p = 0.012`` (the p that decided the row, family-corrected), ``TOST p = …`` when equivalence did;
    the raw p for rows in no family."""
    if row.verdict in (V.EVIDENCE, V.WITHDRAWN):
        return f"raw p = {p_text(row.p)}" if not math.isnan(row.p) else "—"
    if math.isnan(row.p_adj) and math.isnan(row.p_tost_adj):
        return "—"
    p = deciding_p(row)
    kind = "TOST " if p == row.p_tost_adj and row.p_tost_adj != row.p_adj else (
        "minimal-effect " if row.expect == "equivalent" else "")
    return f"{kind}p = {p_text(p)}"


def verdict_text(row: pd.Series) -> str:
    scope = f" [{row.scope.split(' (')[0]}]" if str(row.scope).startswith("scene-dependent") else ""
    note = f" ({row.note})" if row.note else ""
    seq = row.get("seq_text", "")
    # a row run until decided: its replay's clause (its look, or at its cap what a fixed design would cost)
    need = seq if isinstance(seq, str) and seq and row.verdict == V.INCONCLUSIVE else needed_text(row)
    raw = f" [{row.raw_verdict} at raw α]" if row.raw_verdict and row.verdict in (V.EVIDENCE, V.WITHDRAWN) else ""
    beyond = row.get("interval_note", "")
    beyond = f"; {beyond}" if isinstance(beyond, str) and beyond else ""
    return (VERDICT_MARK[row.verdict] + raw + (" — scene-dependent" if scope else "") + note + beyond
            + (f"; {need}" if need else "") + mark_text(row))


def role_text(row: pd.Series, decided: dict[str, str] | None = None) -> str:
    """What the row is for the paper register: "decides `s3_stride_motion`", "evidence for
    `s5_cc_mean` (decided by `secret5_cc.cc_raises_mean_drift`: inconclusive)"."""
    if not row.statement_id:
        return row.group
    text = {"decides": "decides", "evidence": "evidence for", "replaced": "replaced in"}[row.role] + \
        f" `{row.statement_id}`"
    how = (decided or {}).get(row.statement_id, "")
    return text + (f" ({how})" if how and row.role != "decides" else "")


def claims_markdown(frame: pd.DataFrame, decided: dict[str, str] | None = None) -> str:
    """The claims table of a study page: one row per hypothesis with the verdict of the decision
    over every study (the same as reports/index.md's), and the p that decided it; ``decided``:
    each statement's deciding claim and verdict, shown beside the evidence for it."""
    if frame.empty:
        return "This study states no claims."
    lines = ["| Claim | Role | Comparison (metric) | SESOI | Effect [95% CI] | n | Statistic | p (raw) |"
             " p (decided) | Verdict |", "|---|---|---|---:|---|---|---:|---:|---:|---|"]
    for _, r in frame.iterrows():
        stat = f"{r.stat_name} = {r.statistic:.2f}" if not math.isnan(r.statistic) else "—"
        detail = f"; {r.detail}" if r.detail else ""
        lines.append(f"| **{r.id}**: {r.statement} | {role_text(r, decided)} | {r.comparison} (`{r.metric}`{detail}) |"
                     f" {sesoi_text(r)} | {effect_text(r)} | {text(r.n)} | {stat} | {p_text(r.p)} |"
                     f" {p_decided_text(r)} | {verdict_text(r)} |")
    families = families_text(frame)
    methods = sorted({m for m in frame.method if m})
    scales = sorted({r.sesoi_source for _, r in frame.iterrows() if r.sesoi_source})
    changed = [r for _, r in frame.iterrows() if late(r) or r.withdrawn]
    lines += ["", f"Families (every study's claims, as in `reports/index.md`): {'; '.join(families) or 'none tested'}.",
              "", VERDICT_RULES, "", f"Tests: {'; '.join(methods) or 'none run'}.", "",
              "Smallest effects of interest: one per metric, on its own scale (" + "; ".join(scales) + ")."]
    if changed:
        lines += ["", "Claims withdrawn, or not registered before their runs (computed from git):", ""]
        lines += [f"- **{r.id}**: " + "; ".join(filter(None, (
            f"withdrawn — {r.withdrawn}" if r.withdrawn else "",
            f"{EXPLORATORY if exploratory(r) else 'registered after its runs'} {POST_HOC}: {r.registration_note}"
            if late(r) else ""))) for r in changed]
    unknown = [r.id for _, r in frame.iterrows() if r.get("registered_before_runs", "") == "unknown"
               and r.verdict in V.DECIDED]
    if unknown:
        why = sorted({r.registration_note for _, r in frame.iterrows() if r.id in unknown and r.registration_note})
        lines += ["", f"Registered before their runs? Unknown for {', '.join(unknown)}: {'; '.join(why)}."]
    return "\n".join(lines)


def families_text(frame: pd.DataFrame) -> list[str]:
    """One entry per family the study's rows count in: its fixed-n Holm (as a fixed-n row of it
    says, else as its rows run until decided quote it), then the α those rows of this study hold."""
    seq = V.sequential_rows(frame) if len(frame) else pd.Series(dtype=bool)
    out = []
    for group in sorted({str(g) for g, f in zip(frame.group, frame.family) if f}):
        rows = frame[(frame.group.astype(str) == group) & (frame.family != "")]
        fixed = [f for f in rows[~seq[rows.index]].family if f]
        held = rows[seq[rows.index]]
        if not len(held):
            out += sorted(set(fixed))
            continue
        head, _, holm = str(held.family.iloc[0]).partition("; ")
        text = fixed[0] if fixed else f"{head.split(': ')[0]}: {holm}"
        alphas = ", ".join(f"{a:.3g}" for a in sorted({float(a) for a in held.seq_alpha}))
        out.append(f"{text}; this study's {len(held)} {'row' if len(held) == 1 else 'rows'} run until decided"
                   f" at α {alphas}")
    return out


def claims_latex(frame: pd.DataFrame, study: str) -> str:
    """A booktabs table of the claims (needs ``\\usepackage{booktabs}``)."""
    lines = [r"\begin{table}[t]", r"\centering",
             rf"\caption{{{latex_escape(study)}: claims on our runs; effect with 95\% CI, smallest effect of"
             r" interest (SESOI), $p$ that decided the verdict (Holm over every study's family; raw for evidence).}",
             rf"\label{{tab:{study}-claims}}", r"\begin{tabular}{lllrlrl}", r"\toprule",
             r"Claim & Comparison & Effect [95\% CI] & SESOI & $n$ & $p$ & Verdict \\", r"\midrule"]
    for _, r in frame.iterrows():
        lines.append(" & ".join([latex_escape(r.id), latex_escape(r.comparison).replace("−", "$-$"),
                                 latex_escape(effect_text(r)), latex_escape(sesoi_text(r)),
                                 latex_escape(text(r.n)), latex_escape(p_decided_text(r)),
                                 r.verdict + (f" ({EXPLORATORY})" if exploratory(r) else "")]) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}"]
    return "\n".join(lines)


def decoupled_plot(df: pd.DataFrame, claim: ClaimSpec, path: Path) -> Path:
    """Every finished run of ``claim``'s scenes: ``versus`` against ``metric``, a panel per scene,
    colour = variant. Runs in a vertical band as wide as the SESOI have equal RGB quality."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from harness.report.plots import save_figure

    ok = df[(df.status == "FINISHED") & (df.variant.isin(claim.among) if claim.among else True)]  # its search's arms
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
    fig.suptitle(f"{claim.id}: every run (RGB counts as equal within ±{claim.sesoi:g} of {claim.metric})", fontsize=10)
    return save_figure(fig, path)
