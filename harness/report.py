"""``study report NAME``: tables, plots and an index under ``reports/NAME/``.

The runs that count are the study's planned runs for the latest invocation (or for the
selection given on the command line), matched by (variant, scene, seed, config_hash);
for each the latest FINISHED attempt, else the latest failed one (``records.select``).
Written files:

- ``table.md`` / ``table.tex``: the paper-layout tables (``tables.py``), a Welch t-test
  table against the baseline, run counts and the list of failed runs;
- ``strip_<metric>.png``, ``speed_accuracy.png``, ``stability.png`` as the study asks;
- ``diagnostics/<variant>/<scene>/...``: diagnostic images the runs logged under the
  ``diagnostics/`` artifact path (lowest finished seed per cell);
- ``runs.csv`` (one row per run) and ``summary.csv`` (mean, std, CI, t, p per cell);
- ``index.md``: question, exact commands, config hashes, links to all of the above;
- ``claims.csv`` and a "Claims" section in ``table.md``, ``table.tex`` and ``index.md``: each
  claim of the study file with its verdict (``harness.claims``, ``harness.claims_report``);
- ``ladders.csv``, ``ladders.png`` and a "Stability ladders" section in ``table.md`` and
  ``index.md`` when the profile's cells are rungs of difficulty ladders (``harness.ladders``).
"""

from __future__ import annotations

import hashlib

import fnmatch
import math
import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import pandas as pd

from harness import aggregate, claims, claims_report, ladders, plots, speed_accuracy, tables, variance
from harness.plan import PlannedRun, plan_runs
from harness.records import RunRecord, latest_invocation, load_runs, open_store, select
from harness.runner import command_line, tracking_target
from harness.studies import Selection, StudySpec, expand, load_study
from harness.tracking import Store

REPORTS_ROOT = Path("reports")


@dataclass
class ReportData:
    """Everything the report is made from."""

    study: StudySpec
    sel: Selection
    planned: list[PlannedRun]
    df: pd.DataFrame
    uri: str
    experiment: str
    parents: list[RunRecord]
    store: Store | None
    chosen: dict[Any, RunRecord | None] = field(default_factory=dict)


def selection_for(study: StudySpec, sel: Selection | None) -> tuple[Selection, list[PlannedRun]]:
    """The selection to report: the given one, else the latest invocation's, else quick."""
    base = sel or Selection()
    planned = plan_runs(expand(study, base))
    if sel is not None:
        return base, planned
    uri, exp = tracking_target(base, planned)
    inv = latest_invocation(load_runs(open_store(uri), exp, study.name, kind="study"))
    if inv is None:
        return base, planned
    chosen = Selection(**{k: inv[k] for k in ("profile", "seeds", "scenes", "variants", "overrides")})
    return chosen, plan_runs(expand(study, chosen))


def collect(name: str, sel: Selection | None = None, studies_dir: Path | None = None) -> ReportData:
    """Load the study, its plan and its runs (read-only)."""
    study = load_study(name, studies_dir)
    sel, planned = selection_for(study, sel)
    uri, exp = tracking_target(sel, planned)
    store = open_store(uri)
    records = load_runs(store, exp, name)
    parents = load_runs(store, exp, name, kind="study")
    chosen = select(records, planned)
    df = aggregate.runs_frame(chosen, planned)
    return ReportData(study, sel, planned, df, uri, exp, parents, store, chosen)


def _labels(data: ReportData) -> dict[str, str]:
    labels = {p.spec.scene.name: p.spec.scene.title for p in data.planned}
    labels[aggregate.AVERAGE] = "Average"
    return labels


def _order(data: ReportData) -> tuple[list[str], list[str]]:
    prof = data.study.profile(data.sel.profile)
    variants = [v for v in prof.variants if v in set(data.df.variant)]
    scenes = list(dict.fromkeys(data.df.scene))
    return variants, scenes


# Paired per-run differences between conventions, tabulated by the metrics_x_scenes layout.
CONVENTION_GAPS = {
    "gap_lpips_alex": ("lpips_alex_01", "lpips_alex"),
    "gap_lpips_vgg": ("lpips_vgg_01", "lpips_vgg"),
    "gap_ssim": ("ssim2", "ssim1"),
    "gap_dssim": ("dssim2", "dssim1"),
}


def convention_gaps(df: pd.DataFrame) -> pd.DataFrame:
    """``df`` with a ``gap_*`` column per convention pair both of whose metrics it has (per run)."""
    return df.assign(**{g: df[a] - df[b] for g, (a, b) in CONVENTION_GAPS.items()
                        if a in df.columns and b in df.columns})


def _table_metrics(data: ReportData) -> list[str]:
    found = aggregate.match_metrics(data.study.table.metrics, aggregate.metric_columns(data.df))
    literal = [m for m in data.study.table.metrics if not any(ch in m for ch in "*?[")]
    return found or literal


def build_tables(data: ReportData) -> tuple[list[tables.Table], dict[str, pd.DataFrame]]:
    """Paper-layout tables and the per-metric summaries behind them."""
    variants, scenes = _order(data)
    baseline = data.study.profile(data.sel.profile).baseline
    metrics = _table_metrics(data)
    summaries = {m: aggregate.summarize(data.df, m, baseline) for m in metrics}
    labels = _labels(data)
    layout = data.study.table.layout
    if layout == "metrics_x_scenes":
        gap_df = convention_gaps(data.df)
        gaps = {g: aggregate.summarize(gap_df, g, baseline) for g in CONVENTION_GAPS if g in gap_df.columns}
        tabs = [tables.metrics_x_scenes(summaries, baseline, scenes, labels, data.study.name)]
        if gaps:
            gap_table = tables.metrics_x_scenes(gaps, baseline, scenes, labels, f"{data.study.name}-gaps")
            gap_table.title = f"Convention gaps, paired per run ({baseline}): same renders, other convention"
            tabs.append(gap_table)
        return tabs, {**summaries, **gaps}
    if layout == "variants_x_metrics":
        scene = aggregate.AVERAGE if len(scenes) > 1 else scenes[0]
        return [tables.variants_x_metrics(summaries, variants, scene, data.study.name)], summaries
    tabs = [tables.variants_x_scenes(summaries[m], m, variants, scenes, labels, data.study.name) for m in metrics]
    return tabs, summaries


def _fmt(x: float, digits: int = 2) -> str:
    return "—" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


def significance_md(summary: pd.DataFrame, metric: str, baseline: str, labels: dict[str, str]) -> str:
    """Mean [95% CI] and Welch p against the baseline, per variant and scene."""
    d = tables.decimals(metric)
    lines = ["| Variant | Scene | n | mean | 95% CI | Δ vs baseline | Welch t | p |",
             "|---|---|---:|---:|---|---:|---:|---:|"]
    base = summary[summary.variant == baseline].set_index("scene")["mean"]
    if summary.scene.nunique() == 2:  # one scene: its average is the same numbers
        summary = summary[summary.scene != aggregate.AVERAGE]
    for r in summary.itertuples():
        ci = "—" if math.isnan(r.ci95) else f"[{r.mean - r.ci95:.{d}f}, {r.mean + r.ci95:.{d}f}]"
        delta = "" if r.variant == baseline else _fmt(r.mean - base.get(r.scene, math.nan), d)
        lines.append(
            f"| {r.variant} | {labels.get(r.scene, r.scene)} | {r.n} | {_fmt(r.mean, d)} | {ci} | {delta} |"
            f" {_fmt(r.t, 2) if r.variant != baseline else ''} | {_fmt(r.p, 4) if r.variant != baseline else ''} |"
        )
    return "\n".join(lines)


def counts_md(df: pd.DataFrame, labels: dict[str, str]) -> str:
    lines = ["| Variant | Scene | runs | finished | failed | diverged | missing |",
             "|---|---|---:|---:|---:|---:|---:|"]
    for (v, s), sub in df.groupby(["variant", "scene"], sort=False):
        c = aggregate.counts(sub)
        lines.append(f"| {v} | {labels.get(s, s)} | {c['n_runs']} | {c['n_finished']} | {c['n_failed']} |"
                     f" {c['n_diverged']} | {c['n_missing'] + c['n_running']} |")
    return "\n".join(lines)


def failures_md(df: pd.DataFrame) -> str:
    fails = aggregate.failures(df)
    if fails.empty:
        return "No failed, diverged or missing runs."
    lines = ["| Variant | Scene | Seed | Status | Failure | Error | Run |", "|---|---|---:|---|---|---|---|"]
    for r in fails.itertuples():
        err = str(r.error).replace("|", "\\|").replace("\n", " ")[:200]
        lines.append(f"| {r.variant} | {r.scene} | {r.seed} | {r.status} | {r.failure} | {err} | {str(r.run_id)[:8]} |")
    return "\n".join(lines)


def write_tables(data: ReportData, out: Path) -> tuple[list[tables.Table], dict[str, pd.DataFrame]]:
    tabs, summaries = build_tables(data)
    study = data.study
    labels = _labels(data)
    baseline = study.profile(data.sel.profile).baseline
    n_seeds = len(set(data.df.seed))
    md = [f"# {study.name}: tables", "", f"{study.question}", "",
          f"Mean ± std over {n_seeds} seed(s) (seeds {study.base_seed}..{study.base_seed + n_seeds - 1}),"
          " finished runs only; **best** and <u>second best</u> per column. Failed and diverged runs are"
          " counted in the cell's note and listed below.", ""]
    tex = [f"% Generated by `study report {study.name}` ({time.strftime('%Y-%m-%d %H:%M')}).",
           r"% Needs \usepackage{booktabs}.", ""]
    for t in tabs:
        md += [f"## {t.title}", "", tables.to_markdown(t), ""]
        caption = (f"{tables.latex_escape(study.name)}: {tables.latex_escape(t.title)}, mean $\\pm$ std over"
                   f" {n_seeds} seeds; best in bold, second underlined.")
        tex += [tables.to_latex(t, caption), ""]
    if study.table.layout != "metrics_x_scenes":
        for m, s in summaries.items():
            md += [f"## Welch t-test against `{baseline}`: {tables.pretty(m)}", "",
                   significance_md(s, m, baseline, labels), ""]
    md += ["## Runs", "", counts_md(data.df, labels), "",
           "## Failed, diverged or missing runs", "", failures_md(data.df), ""]
    (out / "table.md").write_text("\n".join(md))
    (out / "table.tex").write_text("\n".join(tex))
    return tabs, summaries


def write_plots(data: ReportData, out: Path) -> list[tuple[str, Path]]:
    """The study's figures; returns (caption, path) pairs."""
    variants, scenes = _order(data)
    labels = _labels(data)
    made: list[tuple[str, Path]] = []
    name = data.study.name
    if "strip" in data.study.plots:
        for m in _table_metrics(data)[:1] if data.study.table.layout != "metrics_x_scenes" else []:
            p = plots.strip_plot(data.df, m, variants, scenes, labels, f"{name}: every run's {tables.pretty(m)}",
                                 out / f"strip_{m}.png")
            made.append((f"Per-run {tables.pretty(m)} per variant and scene", p))
    if "speed_accuracy" in data.study.plots and len(scenes) > 1:  # what each scene needs
        sa = speed_accuracy.per_scene(data.df)
        chosen_per_scene = speed_accuracy.smallest_per_scene(sa, data.df)
        sa.to_csv(out / "speed_accuracy.csv", index=False)
        chosen_per_scene.to_csv(out / "speed_accuracy_smallest.csv", index=False)
        p = plots.speed_accuracy_scenes_plot(sa, chosen_per_scene, f"{name}: what does quality cost, per scene?",
                                             out / "speed_accuracy.png")
        made.append(("PSNR against training time and number of Gaussians per scene, Pareto fronts dashed", p))
    elif "speed_accuracy" in data.study.plots:
        sa = aggregate.speed_accuracy(data.df)
        chosen = aggregate.smallest_within(sa)
        sa.to_csv(out / "speed_accuracy.csv", index=False)
        p = plots.speed_accuracy_plot(sa, chosen, f"{name}: what does quality cost?", out / "speed_accuracy.png")
        made.append(("PSNR against training time and number of Gaussians, Pareto front dashed", p))
    if "stability" in data.study.plots:
        st = aggregate.stability(data.df)
        st.to_csv(out / "stability.csv", index=False)
        p = plots.stability_plot(st, variants, scenes, labels, f"{name}: where do methods become unstable?",
                                 out / "stability.png")
        made.append(("Mean ± std PSNR, run-to-run spread and failure rate per difficulty cell", p))
    return made


def write_ladders(data: ReportData, out: Path) -> str:
    """Stability ladders when the profile's cells are rungs (``harness.ladders``): ``ladders.csv``,
    ``ladders.png`` and a section appended to ``table.md``; returns its Markdown ("" when none)."""
    scenes = data.study.profile(data.sel.profile).scenes
    if not ladders.has_ladders(scenes):
        return ""
    md = ladders.write(data.df, scenes, out, f"{data.study.name}: where does each method break?")
    with (out / "table.md").open("a") as f:
        f.write(f"\n## Stability ladders\n\n{md}\n")
    return md


def _artifact_files(store: Store, run_id: str, path: str) -> list[str]:
    files = []
    for info in store.client.list_artifacts(run_id, path):
        files.extend(_artifact_files(store, run_id, info.path) if info.is_dir else [info.path])
    return files


def fetch_diagnostics(data: ReportData, out: Path) -> list[tuple[str, str, int, list[Path]]]:
    """Copy diagnostic images of the lowest finished seed per (variant, scene)."""
    if data.store is None:
        return []
    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
    patterns = list(data.study.diagnostics) or ["*"]
    got = []
    ok = data.df[data.df.status == "FINISHED"].sort_values("seed")
    for (v, s), sub in ok.groupby(["variant", "scene"], sort=False):
        r = sub.iloc[0]
        try:
            files = _artifact_files(data.store, r.run_id, "diagnostics")
        except Exception:  # no diagnostics logged, or an artifact store we cannot list
            continue
        keep = [f for f in files if any(fnmatch.fnmatch(Path(f).name, p) for p in patterns)]
        paths = []
        for f in keep:
            target = out / "diagnostics" / v / s / Path(f).relative_to("diagnostics")
            target.parent.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryDirectory() as tmp:
                shutil.copyfile(data.store.client.download_artifacts(r.run_id, f, tmp), target)
            paths.append(target)
        if paths:
            got.append((v, s, int(r.seed), paths))
    return got


def write_index(data: ReportData, out: Path, tabs: list[tables.Table], figures: list[tuple[str, Path]],
                diags: list[tuple[str, str, int, list[Path]]], claims_md: str = "", variance_md: str = "",
                ladders_md: str = "") -> None:
    study, df = data.study, data.df
    prof = study.profile(data.sel.profile)
    c = aggregate.counts(df)
    cmds = list(dict.fromkeys(p.tags.get("command", "") for p in data.parents
                              if p.tags.get("profile") == data.sel.profile and p.tags.get("command")))
    hashes = sorted({r for r in df.config_hash})
    git = sorted({rec.tags.get("git_sha", "") for rec in data.chosen.values() if rec is not None} - {""})
    lines = [
        f"# Study `{study.name}` ({data.sel.profile} profile)",
        "",
        f"**Question.** {study.question}",
        "",
    ]
    if study.notes:
        lines += [f"**Notes.** {study.notes}", ""]
    lines += [
        f"Runs: {c['n_runs']} planned = {df.variant.nunique()} variants × {df.scene.nunique()} scenes ×"
        f" {df.seed.nunique()} seeds; {c['n_finished']} finished, {c['n_failed']} failed"
        f" ({c['n_diverged']} diverged), {c['n_missing'] + c['n_running']} missing."
        f" Baseline: `{prof.baseline}`. Expected runtime: {prof.expected_runtime or 'n/a'}.",
        "",
        "## Reproduce",
        "",
        "```sh",
        command_line(study.name, data.sel),
        f"study report {study.name}",
        "```",
        "",
    ]
    if cmds:
        lines += ["Invocations that produced these runs:", "", *[f"- `{cmd}`" for cmd in cmds], ""]
    lines += determinism_md(df)
    if claims_md:
        lines += ["## Claims", "", claims_md, ""]
    if variance_md:
        lines += ["## Sources of run-to-run spread", "", variance_md, ""]
    if ladders_md:
        lines += ["## Stability ladders", "", ladders_md, ""]
    lines += ["## Tables", "",
              "Full tables, t-tests and failures: [table.md](table.md); LaTeX: [table.tex](table.tex);",
              "per-run data: [runs.csv](runs.csv), per-cell statistics: [summary.csv](summary.csv).", ""]
    if tabs:
        lines += [f"### {tabs[0].title}", "", tables.to_markdown(tabs[0]), ""]
    if "speed_accuracy" in study.plots and df.scene.nunique() > 1:
        lines += [speed_accuracy.report_markdown(df), "",
                  "Per scene and variant: [speed_accuracy.csv](speed_accuracy.csv); the chosen budgets:"
                  " [speed_accuracy_smallest.csv](speed_accuracy_smallest.csv).", ""]
    elif "speed_accuracy" in study.plots:
        sa = aggregate.speed_accuracy(df)
        chosen = aggregate.smallest_within(sa)
        if chosen is not None and sa.budget.nunique() > 1:  # a budget sweep (not e.g. a learning-rate one)
            lines += [f"**Smallest budget within 0.1 dB of the best:** `{chosen['variant']}` — budget"
                      f" {int(chosen['budget'])} Gaussians, {int(chosen['iterations'])} iterations,"
                      f" PSNR {chosen['mean']:.2f} dB, {chosen['train_seconds']:.1f} s of training.", ""]
    if figures:
        lines += ["## Plots", ""]
        for caption, p in figures:
            lines += [f"### {caption}", "", f"![{caption}]({p.relative_to(out).as_posix()})", ""]
    if diags:
        lines += ["## Diagnostics", "",
                  "Logged by the runs under the `diagnostics/` artifact path (lowest finished seed).", ""]
        for v, s, seed, paths in diags:
            lines += [f"### {v} / {s} (seed {seed})", ""]
            lines += [_embed(p, out) for p in paths] + [""]
    lines += [
        "## Config hashes",
        "",
        "`config_hash` = hash of the resolved training config (without output/logging keys)"
        " plus the synthetic scene's generator arguments; runs are resumed and matched by it.",
        "",
        "<details><summary>" + f"{len(hashes)} config hashes" + "</summary>",
        "",
        "| Variant | Scene | Seed | config_hash | Status | MLflow run |",
        "|---|---|---:|---|---|---|",
        *[f"| {r.variant} | {r.scene} | {r.seed} | `{r.config_hash}` | {r.status} | {str(r.run_id)[:8]} |"
          for r in df.itertuples()],
        "",
        "</details>",
        "",
        "## Tracking",
        "",
        f"MLflow store `{_display_uri(data.uri)}`, experiment `{data.experiment}`; code at {', '.join(git) or 'unknown'}.",
        f"Parent runs: {', '.join(p.run_id[:8] for p in data.parents) or 'none'}. Browse them with:",
        "",
        "```sh",
        f"mlflow ui --backend-store-uri {_display_uri(data.uri)}" if data.uri.startswith("sqlite") else f"open {data.uri}",
        "```",
        "",
        f"_Generated by `study report {study.name}` on {time.strftime('%Y-%m-%d %H:%M')}._",
        "",
    ]
    (out / "index.md").write_text("\n".join(lines))


FINGERPRINT = ".fingerprint"  # what a report was made from: its runs and the code that wrote it


def fingerprint(df: pd.DataFrame) -> str:
    """A hash of the planned runs (run id, status, every metric) and of the harness code
    version: equal fingerprints mean the report would come out the same."""
    from harness.provenance import git_sha

    cols = sorted(c for c in df.columns if c not in ("scene_label",))
    blob = df[cols].sort_values(["variant", "scene", "seed"]).to_csv(index=False) + git_sha()
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def write_report(name: str, sel: Selection | None = None, *, studies_dir: Path | None = None,
                 reports_root: Path = REPORTS_ROOT, echo: Callable[[str], None] = print,
                 if_changed: bool = False, skip_empty: bool = False) -> Path | None:
    """Write ``reports/<name>/`` and return its index path. ``if_changed``: leave the report as
    it is when its runs and the code are those it was made from (``.fingerprint``).
    ``skip_empty``: write nothing (and return None) for a study without finished runs."""
    data = collect(name, sel, studies_dir)
    if skip_empty and not (data.df.status == "FINISHED").any():
        echo(f"{name}: no finished runs, no report")
        return None
    out = Path(reports_root) / name
    stamp = fingerprint(data.df)
    if if_changed and (out / FINGERPRINT).is_file() and (out / FINGERPRINT).read_text().strip() == stamp:
        echo(f"{name}: report up to date ({out / 'index.md'})")
        return out / "index.md"
    out.mkdir(parents=True, exist_ok=True)
    data.df.to_csv(out / "runs.csv", index=False)
    tabs, summaries = write_tables(data, out)
    claims_md = write_claims(data, out)
    variance_md = write_variance(data, out)
    ladders_md = write_ladders(data, out)
    if summaries:
        pd.concat(summaries.values(), ignore_index=True).to_csv(out / "summary.csv", index=False)
    figures = write_plots(data, out)
    diags = fetch_diagnostics(data, out)
    write_index(data, out, tabs, figures, diags, claims_md, variance_md, ladders_md)
    (out / FINGERPRINT).write_text(stamp + "\n")
    c = aggregate.counts(data.df)
    echo(f"{name}: report of {c['n_runs']} runs ({c['n_finished']} finished, {c['n_failed']} failed,"
         f" {c['n_missing'] + c['n_running']} missing) written to {out / 'index.md'}")
    return out / "index.md"


def determinism_md(df: pd.DataFrame) -> list[str]:
    """Which determinism domains the runs come from; a warning for cells that mix domains."""
    doms = aggregate.domains(df)
    if doms.empty:
        return []
    lines = ["## Determinism", ""]
    if len(doms) == 1:
        d = doms.iloc[0]
        lines.append(f"All {d.runs} finished runs come from one determinism domain: `{d.domain}` ({d['mode']} mode,"
                     f" torch kernels {d.cpu_capability}, {d.torch_threads} torch thread(s), {d.cpu_model}).")
    else:
        lines += [f"**Runs from {len(doms)} determinism domains.** Numbers of different domains need not agree"
                  " bit for bit (ftgspp/determinism.py; portable-mode runs reproduce on any x86-64 machine with"
                  " the same package versions).", "",
                  "| domain | mode | torch kernels | threads | CPU | runs | variants |", "|---|---|---|---:|---|---:|---|"]
        lines += [f"| `{d.domain}` | {d['mode']} | {d.cpu_capability} | {d.torch_threads} | {d.cpu_model} | {d.runs} |"
                  f" {d.variants} |" for _, d in doms.iterrows()]
    mixed = doms.attrs["mixed_cells"]
    if mixed:
        lines += ["", f"**Warning:** these cells mix runs of different domains: {', '.join(mixed)}."]
    return lines + [""]


def write_variance(data: ReportData, out: Path) -> str:
    """The study's ``variance_components`` (optimisation, initialisation, hardware) as
    ``variance.csv`` and Markdown; "" when the study names none."""
    if data.study.variance is None:
        return ""
    frame = variance.components(data.df, data.study.variance)
    frame.to_csv(out / "variance.csv", index=False)
    md = variance.components_markdown(frame)
    with (out / "table.md").open("a") as f:
        f.write(f"\n## Sources of run-to-run spread\n\n{md}\n")
    return md


# --- claims: the study file's claims with verdicts (harness/claims.py) -------------------


def write_claims(data: ReportData, out: Path) -> str:
    """Test the study's claims on its runs: ``claims.csv``, a "Claims" section appended to
    ``table.md`` and ``table.tex``; returns the Markdown ("" when the study states none)."""
    if not data.study.claims:
        return ""
    frame = claims.evaluate(convention_gaps(data.df), data.study.claims)
    frame.to_csv(out / "claims.csv", index=False)
    md = claims_report.claims_markdown(frame)
    for c, r in zip(data.study.claims, frame.effect):
        if c.test == "correlation":  # secret 2: the runs behind "clean RGB does not imply clean motion"
            p = claims_report.correlation_plot(data.df, c, r, out / f"claim_{c.id}.png")
            md += f"\n\n![{c.id}: {c.versus} against {c.metric}, every run]({p.name})"
    with (out / "table.md").open("a") as f:
        f.write(f"\n## Claims\n\n{md}\n")
    with (out / "table.tex").open("a") as f:
        f.write("\n" + claims_report.claims_latex(frame, data.study.name) + "\n")
    return md


def _embed(path: Path, root: Path) -> str:
    """Markdown for one diagnostic file: images inline, anything else (JSON numbers) as a link."""
    rel = path.relative_to(root).as_posix()
    if path.suffix.lower() in {".png", ".jpg", ".jpeg", ".svg"}:
        return f"![{path.name}]({rel})"
    return f"[{path.name}]({rel})"


def _display_uri(uri: str) -> str:
    """A SQLite URI inside the working directory as the relative ``sqlite:///mlflow.db`` a reader can reuse."""
    prefix = "sqlite:///"
    if uri.startswith(prefix):
        path = Path(uri[len(prefix):])
        try:
            return prefix + path.relative_to(Path.cwd()).as_posix()
        except ValueError:
            return uri
    return uri
