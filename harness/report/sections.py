"""The parts of a study's report. Each returns what it contributes and writes only its own files.

- ``tables_section``: the paper-layout tables with their Welch tests, run counts and
  failures (the body of ``table.md`` and ``table.tex``);
- ``claims_section``, ``variance_section``, ``ladders_section``: a ``Section`` each (its
  Markdown for ``table.md`` and ``index.md``, LaTeX, and its CSV/PNG files), or ``None``
  when the study has nothing of the kind;
- ``figures``: the plots the study asks for; ``diagnostics``: the runs' diagnostic images;
- ``determinism_lines``: which determinism domains the runs come from.

``report.writer`` assembles them, in a fixed order, into the report's files.
"""

from __future__ import annotations

import dataclasses
import fnmatch
import math
import time
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from harness.analysis import aggregate, ladder_breaks, speed_accuracy_scenes, variance, verdicts
from harness.report import claims_table, committed, families, ladder_figures, pareto_plots, plots, tables
from harness.report.fmt import fixed
from harness.report.results import ReportData
from harness.spec import metrics as registry
from harness.spec.study_files import load_register
from harness.spec.study_schema import plural


@dataclass
class Section:
    """One titled part of a report: Markdown (``table.md`` and ``index.md``) and LaTeX."""

    title: str
    md: str
    tex: str = ""


@dataclass
class TablesSection:
    """The main tables: their ``table.md`` / ``table.tex`` text and the summaries behind them."""

    tables: list[tables.Table]
    summaries: dict[str, pd.DataFrame]
    md: str
    tex: str


def table_metrics(data: ReportData) -> list[str]:
    """The study's table metrics that the runs logged (patterns expanded), else as written."""
    found = aggregate.match_metrics(data.study.table.metrics, aggregate.metric_columns(data.df))
    literal = [m for m in data.study.table.metrics if not any(ch in m for ch in "*?[")]
    return found or literal


def build_tables(data: ReportData) -> tuple[list[tables.Table], dict[str, pd.DataFrame]]:
    """Paper-layout tables and the per-metric summaries behind them."""
    variants, scenes = data.shown_order()  # a scene's fresh instances as one column (ReportData.shown)
    shown = data.shown()
    baseline = data.baseline
    metrics = table_metrics(data)
    summaries = {m: aggregate.summarize(shown, m, baseline) for m in metrics}
    labels = data.labels()
    layout = data.study.table.layout
    if layout == "metrics_x_scenes":
        gap_df = registry.add_differences(shown)
        gaps = {g: aggregate.summarize(gap_df, g, baseline) for g in registry.differences() if g in gap_df.columns}
        tabs = [tables.metrics_x_scenes(summaries, baseline, scenes, labels, data.study.name)]
        if gaps:
            gap_table = tables.metrics_x_scenes(gaps, baseline, scenes, labels, f"{data.study.name}-gaps")
            gap_table.title = f"Convention gaps, paired per run ({baseline}): same renders, other convention"
            tabs.append(gap_table)
        return tabs, {**summaries, **gaps}
    if layout == "variants_x_metrics":
        scene = aggregate.AVERAGE if len(scenes) > 1 else scenes[0]
        return [tables.variants_x_metrics(summaries, variants, scene, data.study.name)], summaries
    tabs = [tables.variants_x_scenes(summaries[m], m, variants, scenes, labels, data.study.name,
                                     data.study.table.unranked) for m in metrics]
    return tabs, summaries


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
        delta = "" if r.variant == baseline else fixed(r.mean - base.get(r.scene, math.nan), d)
        lines.append(
            f"| {r.variant} | {labels.get(r.scene, r.scene)} | {r.n} | {fixed(r.mean, d)} | {ci} | {delta} |"
            f" {fixed(r.t, 2) if r.variant != baseline else ''} | {fixed(r.p, 4) if r.variant != baseline else ''} |"
        )
    return "\n".join(lines)


def counts_md(df: pd.DataFrame, labels: dict[str, str]) -> str:
    """Runs, finished, failed, diverged and missing per (variant, scene)."""
    lines = ["| Variant | Scene | runs | finished | failed | diverged | missing |",
             "|---|---|---:|---:|---:|---:|---:|"]
    for (v, s), sub in df.groupby(["variant", "scene"], sort=False):
        c = aggregate.counts(sub)
        lines.append(f"| {v} | {labels.get(s, s)} | {c['n_runs']} | {c['n_finished']} | {c['n_failed']} |"
                     f" {c['n_diverged']} | {c['n_missing'] + c['n_running']} |")
    return "\n".join(lines)


def failures_md(df: pd.DataFrame) -> str:
    """Every run that did not finish, with its failure and error."""
    fails = aggregate.failures(df)
    if fails.empty:
        return "No failed, diverged or missing runs."
    lines = ["| Variant | Scene | Seed | Status | Failure | Error | Run |", "|---|---|---:|---|---|---|---|"]
    for r in fails.itertuples():
        err = str(r.error).replace("|", "\\|").replace("\n", " ")[:200]
        lines.append(f"| {r.variant} | {r.scene} | {r.seed} | {r.status} | {r.failure} | {err} | {str(r.run_id)[:8]} |")
    return "\n".join(lines)


def tables_section(data: ReportData) -> TablesSection:
    """The tables in Markdown and LaTeX, Welch tests against the baseline, counts and failures."""
    tabs, summaries = build_tables(data)
    study = data.study
    labels = data.labels()
    baseline = data.baseline
    n_seeds = len(set(data.df.seed))
    md = [f"# {study.name}: tables", "", f"{study.question}", "",
          f"Mean ± std over {plural(n_seeds, 'seed')} (seeds {study.base_seed}..{study.base_seed + n_seeds - 1}),"
          " finished runs only; **best** and <u>second best</u> per column, each marked only when Welch's t"
          " separates it from the next (p < 0.05). Failed and diverged runs are"
          " counted in the cell's note and listed below." + (
              " A scene's \"fresh instances\" column is over its fresh synthetic instances instead, one run"
              " each (the claims' unit; docs/sequential.md)" if data.shown() is not data.df else ""), ""]
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
    md += ["## Runs", "", counts_md(data.shown(), labels), "",
           "## Failed, diverged or missing runs", "", failures_md(data.df), ""]
    return TablesSection(tabs, summaries, "\n".join(md), "\n".join(tex))


def claims_section(data: ReportData, out: Path, decided: pd.DataFrame | None,
                   profile: str | None = None) -> Section | None:
    """The study's claims tested on its runs, with ``decided``, the study's rows of the decision
    over every study (``report.families.study_frame``: the same as ``reports/index.md``'s, every
    study read at ``profile`` when given); ``claims.csv``, a scatter per existential claim."""
    if not data.study.claims:
        return None
    frame = decided
    if frame is None:  # no finished run here or anywhere the index reads: the claims, untested
        frame = verdicts.decide(verdicts.evaluate(registry.add_differences(data.df), data.study.claims,
                                                  data.study.name, load_register()), label=families.EVERY_STUDY)
    frame.to_csv(out / "claims.csv", index=False)
    md = claims_table.claims_markdown(frame, families.deciding_verdicts(out.parent, profile=profile))
    for c in data.study.claims:
        if c.test in ("decoupled", "dissociated"):  # secret 2: "clean RGB does not imply clean motion"
            p = claims_table.decoupled_plot(data.df, c, out / f"claim_{c.id}.png")
            md += f"\n\n![{c.id}: {c.versus} against {c.metric}, every run]({p.name})"
    return Section("Claims", md, claims_table.claims_latex(frame, data.study.name))


def variance_section(data: ReportData, out: Path) -> Section | None:
    """The study's ``variance_components`` (optimisation, initialisation, hardware): ``variance.csv``."""
    if data.study.variance is None:
        return None
    frame = variance.components(data.df, data.study.variance)
    frame.to_csv(out / "variance.csv", index=False)
    return Section("Sources of run-to-run spread", components_markdown(frame))


def components_markdown(frame: pd.DataFrame) -> str:
    """The components as a Markdown table plus the largest same-seed range across dispatches."""
    metric = frame.attrs.get("metric", "")
    lines = [f"| component | SD of {metric} | 95% CI | df | runs | how |", "|---|---:|---:|---:|---:|---|"]
    for r in frame.itertuples():
        ci = "" if not math.isfinite(r.ci_low) else f"[{r.ci_low:.4f}, {r.ci_high:.4f}]"
        sd = "n/a" if not math.isfinite(r.sd) else f"{r.sd:.4f}"
        lines.append(f"| {r.component} | {sd} | {ci} | {r.dof} | {r.n_runs} | {r.how} |")
    rng = frame.attrs.get("hardware_max_range", math.nan)
    if math.isfinite(rng):
        lines += ["", f"Largest same-seed, same-initialisation range across kernel dispatches: {rng:.4f}."]
    hw = frame[frame.component.str.startswith("hardware")]
    if len(hw) and math.isfinite(float(hw.sd.iloc[0])):
        lines += ["", "The hardware component is a property of the host as much as of the method: it is how far"
                  " the same run moves between kernel dispatches of *this* CPU (its AVX2 and x86-64 baseline"
                  " kernels), whose rounding differs from one CPU vendor and vector width to another. Runs on"
                  " another host measure its own value — read it against the 95% CI above, not as a"
                  " reproduction failure."]
    return "\n".join(lines)


def ladders_section(data: ReportData, out: Path) -> Section | None:
    """Stability ladders when the profile's cells are rungs: ``ladders.csv`` and ``ladders.png``."""
    scenes = data.study.profile(data.sel.profile).scenes
    if not ladder_breaks.has_ladders(scenes):
        return None
    md = ladder_figures.write(data.df, scenes, out, f"{data.study.name}: where does each method break?",
                              data.baseline)
    return Section("Stability ladders", md)


def figures(data: ReportData, out: Path) -> list[tuple[str, Path]]:
    """The study's figures (and the CSVs behind them); returns (caption, path) pairs."""
    variants, scenes = data.order()
    labels = data.labels()
    made: list[tuple[str, Path]] = []
    name = data.study.name
    if "strip" in data.study.plots:
        shown_variants, shown_scenes = data.shown_order()
        for m in table_metrics(data)[:1] if data.study.table.layout != "metrics_x_scenes" else []:
            p = plots.strip_plot(data.shown(), m, shown_variants, shown_scenes, labels,
                                 f"{name}: every run's {tables.pretty(m)}", out / f"strip_{m}.png")
            made.append((f"Per-run {tables.pretty(m)} per variant and scene", p))
    if "speed_accuracy" in data.study.plots and len(scenes) > 1:  # what each scene needs
        sa = speed_accuracy_scenes.per_scene(data.df)
        chosen_per_scene = speed_accuracy_scenes.smallest_per_scene(sa, data.df)
        sa.to_csv(out / "speed_accuracy.csv", index=False)
        chosen_per_scene.to_csv(out / "speed_accuracy_smallest.csv", index=False)
        logged = [m for m in ("psnr", "psnr_cc", "lpips_alex") if m in data.df and data.df[m].notna().any()]
        per = {m: sa if m == "psnr" else speed_accuracy_scenes.per_scene(data.df, m) for m in logged}
        if "psnr_cc" in per:  # the model's own need (report.answers)
            speed_accuracy_scenes.smallest_per_scene(per["psnr_cc"], data.df, metric="psnr_cc").to_csv(
                out / "speed_accuracy_smallest_psnr_cc.csv", index=False)
        first = speed_accuracy_scenes.method_of(data.baseline)
        if not (cmp := speed_accuracy_scenes.method_comparison(data.df, first)).empty:
            cmp.to_csv(out / "method_comparison.csv", index=False)
        files = {"psnr": "speed_accuracy.png", "psnr_cc": "speed_accuracy_psnr_cc.png",
                 "lpips_alex": "speed_accuracy_lpips_alex.png"}
        for metric, cells in per.items():
            p = pareto_plots.pareto_plot(cells, metric, f"{name}: {tables.pretty(metric)} against cost, per scene",
                                         out / files[metric])
            made.append((f"{tables.pretty(metric)} against training time, render speed and model size per scene,"
                         " each method's Pareto front dashed", p))
    elif "speed_accuracy" in data.study.plots:
        sa = aggregate.speed_accuracy(data.df)
        chosen = aggregate.smallest_within(sa)
        sa.to_csv(out / "speed_accuracy.csv", index=False)
        p = plots.speed_accuracy_plot(sa, chosen, f"{name}: what does quality cost?", out / "speed_accuracy.png")
        made.append(("PSNR against training time and number of Gaussians, Pareto front dashed", p))
    if "stability" in data.study.plots:
        metric = "psnr_cc" if "psnr_cc" in data.df else "psnr"
        st = aggregate.stability(data.df, metric)
        if ladder_breaks.has_ladders(data.study.profile(data.sel.profile).scenes):  # the ladders' failure kinds
            rates = ladder_breaks.cell_break_rates(data.df, data.study.profile(data.sel.profile).scenes, data.baseline)
            st = st.drop(columns="failure_rate").merge(rates.rename(columns={"break_rate": "failure_rate"}),
                                                       on=["variant", "scene"], how="left")
            st.attrs["metric"] = metric
        st.to_csv(out / "stability.csv", index=False)
        p = plots.stability_plot(st, variants, scenes, labels, f"{name}: where do methods become unstable?",
                                 out / "stability.png")
        made.append(("Mean ± std PSNR, run-to-run spread and failure rate per difficulty cell", p))
    return made


def _diagnostic_files(data: ReportData, runs: pd.DataFrame, patterns: list[str]) -> tuple[pd.Series, list[str]] | None:
    """The lowest seed of ``runs`` that logged a figure the study shows (only a study's first
    seed draws them), else the lowest that logged any matching file; with those files."""
    fallback = None
    for _, r in runs.iterrows():
        try:
            files = data.store.artifact_files(r.run_id, "diagnostics")
        except Exception:  # no diagnostics logged, or an artifact store we cannot list
            continue
        keep = [f for f in files if any(fnmatch.fnmatch(Path(f).name, p) for p in patterns)]
        if any(f.endswith(".png") for f in keep):
            return r, keep
        if keep and fallback is None:
            fallback = (r, keep)
    return fallback


def diagnostics(data: ReportData, out: Path) -> list[tuple[str, str, int, list[Path]]]:
    """Copy the diagnostics the study file names (``diagnostics:``, file-name patterns; none when it
    names none) of the lowest finished seed with figures per (variant, scene) into
    ``out/diagnostics/<variant>/<scene>/``; returns (variant, scene, seed, files). A report from
    committed runs reuses the committed report's files (``report.committed``)."""
    if data.recorded is not None:
        return committed.diagnostics(data, out)
    patterns = list(data.study.diagnostics)  # a study that names none copies none (they are in the store)
    if data.store is None or not patterns:
        return []
    if "instance" in data.df:  # a fresh instance (one run) has the figures of its scene as written
        data = dataclasses.replace(data, df=data.df[data.df.instance == 0])
    skip = committed.filled_cells(data)
    got = committed.filled_diagnostics(data, out, skip)  # cells whose runs the store lacks: the committed files
    ok = data.df[data.df.status == "FINISHED"].sort_values("seed")
    for (v, s), sub in ok.groupby(["variant", "scene"], sort=False):
        if (v, s) in skip:
            continue
        found = _diagnostic_files(data, sub, patterns)
        if found is None:
            continue
        r, keep = found
        paths = data.store.copy_artifacts(r.run_id, keep, out / "diagnostics" / v / s, under="diagnostics")
        if paths:
            got.append((v, s, int(r.seed), paths))
    order = {cell: i for i, cell in enumerate(dict.fromkeys(zip(data.df.variant, data.df.scene)))}
    return sorted(got, key=lambda g: order.get((g[0], g[1]), len(order)))


def determinism_lines(df: pd.DataFrame) -> list[str]:
    """Which determinism domains the runs come from; a warning for cells that mix domains."""
    doms = aggregate.domains(df)
    if doms.empty:
        return []
    lines = ["## Determinism", ""]
    if len(doms) == 1:
        d = doms.iloc[0]
        lines.append(f"All {d.runs} finished runs come from one determinism domain: `{d.domain}` ({d['mode']} mode,"
                     f" torch kernels {aggregate.kernel_set(d.cpu_capability)},"
                     f" {plural(int(d.torch_threads), 'torch thread')}, {d.cpu_model}).")
    else:
        lines += [f"**Runs from {len(doms)} determinism domains.** Numbers of different domains need not agree"
                  " bit for bit (ftgspp/runtime/determinism.py; portable-mode runs reproduce on any x86-64 machine with"
                  " the same package versions).", "",
                  "| domain | mode | torch kernels | threads | CPU | runs | variants |", "|---|---|---|---:|---|---:|---|"]
        lines += [f"| `{d.domain}` | {d['mode']} | {aggregate.kernel_set(d.cpu_capability)} | {d.torch_threads} | {d.cpu_model} | {d.runs} |"
                  f" {d.variants} |" for _, d in doms.iterrows()]
    mixed = doms.attrs["mixed_cells"]
    if mixed:
        lines += ["", f"**Warning:** these cells mix runs of different domains: {', '.join(mixed)}."]
    return lines + [""]
