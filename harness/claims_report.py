"""Claims in reports: the "Claims" table of ``study report NAME`` and ``reports/index.md``.

``claims_markdown`` / ``claims_latex`` render the frame ``harness.claims.evaluate`` returns;
``correlation_plot`` draws the runs behind a correlation claim (secret 2: motion error
against PSNR over every run and variant).
``write_claims_index`` (``study index``) builds the page a reader opens first: one row per
claim of every study that has runs in the store (the paper's claim and number, our effect
± 95% CI with n and Holm p, the verdict, a link to the study's report), then the
speed–accuracy and stability charts when their reports exist. The page carries no
timestamp, so the same store gives the same page.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import pandas as pd

from harness import claims as claims_mod
from harness.studies import ClaimSpec
from harness.tables import decimals, latex_escape, pretty

VERDICT_MARK = {claims_mod.REPRODUCED: "✅ reproduced", claims_mod.CONTRADICTED: "❌ contradicted",
                claims_mod.INCONCLUSIVE: "❔ inconclusive", claims_mod.NOT_TESTED: "— not tested"}
CHARTS = (("speed_accuracy", "speed_accuracy.png", "Speed against accuracy per scene (PSNR vs train time and"
                                                    " #Gaussians, Pareto fronts)"),
          ("stability", "ladders.png", "Stability ladders: PSNR and failure rate (crash, divergence, collapse) per rung"),
          ("stability", "stability.png", "Stability: PSNR, spread and failure rate per difficulty cell"))


def _num(x: float, digits: int, sign: bool = False) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "—"
    return f"{x:+.{digits}f}" if sign else f"{x:.{digits}f}"


def _text(x: object) -> str:
    """A cell's text: "—" for None, NaN and the empty string."""
    return "—" if x is None or x == "" or (isinstance(x, float) and math.isnan(x)) else str(x)


def _p(p: float) -> str:
    return "—" if math.isnan(p) else f"{p:.2g}" if p >= 1e-4 else f"{p:.1e}"


def _digits(row: pd.Series) -> int:
    return 3 if row.test == "correlation" else decimals(row.metric)


def effect_text(row: pd.Series) -> str:
    """``+0.42 [+0.31, +0.53]`` (effect and 95% CI in the metric's precision)."""
    if math.isnan(row.effect):
        return "—"
    d = _digits(row)
    return f"{_num(row.effect, d, True)} [{_num(row.ci_low, d, True)}, {_num(row.ci_high, d, True)}]"


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
        lines.append(f"| **{r.id}**: {r.statement} | {_text(r.paper_number)} | {r.comparison} (`{r.metric}`{detail}) |"
                     f" {effect_text(pd.Series(r._asdict()))} | {_text(r.n)} | {stat} | {_p(r.p_holm)} |"
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
                                 latex_escape(_text(r.n)), latex_escape(_p(r.p_holm)), r.verdict]) + r" \\")
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


# --------------------------------------------------------------------------- reports/index.md


@dataclass
class StudyClaims:
    """One study's entry of the index page."""

    study: str
    question: str
    frame: pd.DataFrame  # claims.evaluate
    report: str  # link to the study's report, relative to the index page
    n_finished: int
    code: str = ""  # git sha(s) of the runs


def index_markdown(entries: list[StudyClaims], charts: list[tuple[str, str]], missing: list[str]) -> str:
    """The page: a claims table over every study, the charts, and the studies without runs."""
    lines = ["# The answers: every claim of the paper on our runs", "",
             "One row per claim of every study with runs in the store. Effect = the compared quantity"
             " (see the study's report for the exact test) with its 95% CI; n = runs or seed pairs;"
             " p Holm-corrected within the study. Regenerate with `make reports` (or `study index`).", "",
             "| Study | Claim | Paper | Ours: effect [95% CI] (n, p) | Verdict | Report |",
             "|---|---|---|---|---|---|"]
    for e in entries:
        for _, r in e.frame.iterrows():
            ours = "—" if math.isnan(r.effect) else f"{effect_text(r)} ({r.n}, p = {_p(r.p_holm)})"
            note = f" ({r.note})" if r.note else ""
            need = needed_text(r)
            if need.startswith("none"):
                need = f"; no n gives 80% power: {need[6:-1]}"
            elif need:
                need = f"; ≈{need}{'' if need.endswith('runs') else ' runs/arm'} for 80% power"
            lines.append(f"| {e.study} | {r.statement} | {_text(r.paper_number)} | {ours} |"
                         f" {VERDICT_MARK[r.verdict]}{note}{need} | [{e.study}]({e.report}) |")
        if e.frame.empty:
            lines.append(f"| {e.study} | (no claims stated) | — | — | — | [{e.study}]({e.report}) |")
    lines.append("")
    counts = pd.Series([v for e in entries for v in e.frame.verdict]).value_counts()
    if len(counts):
        lines += ["Verdicts: " + ", ".join(f"{int(counts.get(v, 0))} {v}" for v in VERDICT_MARK) + ".", ""]
    for caption, path in charts:
        lines += [f"## {caption}", "", f"![{caption}]({path})", ""]
    if missing:
        lines += ["## Studies without runs yet", "", *[f"- `{m}`: `study run {m} --profile quick`" for m in missing],
                  ""]
    codes = sorted({c for e in entries for c in e.code.split(", ") if c})
    lines += [f"Runs made by code {', '.join(codes) or 'unknown'}."
              + (" **More than one code version: regenerate from one.**" if len(codes) > 1 else ""), ""]
    return "\n".join(lines)


def collect_study_claims(name: str, studies_dir: Path | None = None) -> StudyClaims | None:
    """The study's claims evaluated on its latest invocation's runs; None when none finished."""
    from harness.report import collect, convention_gaps

    data = collect(name, None, studies_dir)
    n_done = int((data.df.status == "FINISHED").sum())
    if n_done == 0:
        return None
    frame = claims_mod.evaluate(convention_gaps(data.df), data.study.claims)
    git = sorted({rec.tags.get("git_sha", "") for rec in data.chosen.values() if rec is not None} - {""})
    report = (Path(name) / "index.md").as_posix()
    return StudyClaims(name, data.study.question, frame, report, n_done, ", ".join(git))


def write_claims_index(reports_root: Path = Path("reports"), studies_dir: Path | None = None,
                       echo: Callable[[str], None] = print) -> Path:
    """Write ``reports_root/index.md`` over every study in ``studies_dir``; return its path."""
    from harness.studies import list_studies

    root = Path(reports_root)
    root.mkdir(parents=True, exist_ok=True)
    entries, missing = [], []
    for name in list_studies(studies_dir):
        entry = collect_study_claims(name, studies_dir)
        (entries.append(entry) if entry is not None else missing.append(name))
    charts = [(caption, f"{study}/{png}") for study, png, caption in CHARTS if (root / study / png).is_file()]
    path = root / "index.md"
    path.write_text(index_markdown(entries, charts, missing))
    n = sum(len(e.frame) for e in entries)
    echo(f"index: {n} claims over {len(entries)} studies with runs ({len(missing)} without) written to {path}")
    return path
