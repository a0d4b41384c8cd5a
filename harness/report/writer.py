"""``study report NAME``: tables, plots and an index under ``reports/NAME/``.

The runs that count are the study's planned runs for the latest invocation (or for the
selection given on the command line), matched by (variant, scene, seed, config_hash);
for each the latest FINISHED attempt, else the latest failed one (``report.results``).
Written files:

- ``table.md`` / ``table.tex``: the paper-layout tables (``report.tables``), a Welch t-test
  table against the baseline, run counts and the list of failed runs;
- ``strip_<metric>.png``, ``speed_accuracy.png``, ``stability.png``, ``xt_grid_<scene>.png``
  (``report.xt_figures``) as the study asks;
- ``diagnostics/<variant>/<scene>/...``: diagnostic images the runs logged under the
  ``diagnostics/`` artifact path (lowest finished seed with figures per cell);
- ``runs.csv`` (one row per run) and ``summary.csv`` (mean, std, CI, t, p per cell);
- ``index.md``: question, exact commands, config hashes, links to all of the above; first, when
  the runs were made by another trainer than this checkout's, a note saying so with the command
  that refreshes them and its expected time here (``report.currency``);
- ``claims.csv`` and a "Claims" section in ``table.md``, ``table.tex`` and ``index.md``: each
  claim of the study file with its verdict (``analysis.claim_tests``, ``report.claims_table``);
- ``variance.csv`` and a "Sources of run-to-run spread" section when the study names
  ``variance_components``;
- ``ladders.csv``, ``ladders.png`` and a "Stability ladders" section in ``table.md`` and
  ``index.md`` when the profile's cells are rungs of difficulty ladders (``report.ladder_figures``).

In MLflow, on the parent run of the reported runs: a tag ``verdict.<claim>`` per claim, the
verdicts and the per-variant means at the registry's decimals as artifacts and as the run's
description (``report.mlflow_answer``).

Each part comes from ``report.sections``; this module puts them together in a fixed order.
When the tracking store has none of the reported runs, they come from the committed report
(``report.committed``), and the page's last line says so.
"""

from __future__ import annotations

import hashlib
import shutil
import time
from pathlib import Path
from typing import Callable

import pandas as pd

from harness.analysis import aggregate
from harness.report import (
    COMMITTED_REPORTS,
    USER_REPORTS,
    committed,
    currency,
    families,
    mlflow_answer,
    sections,
    speed_accuracy_text,
    tables,
    xt_figures,
)
from harness.report.results import ReportData, collect
from harness.spec.runs import Selection, command_line, study_ref
from harness.spec.study_schema import plural
from harness.tracking.conventions import browse_command
from harness.tracking.provenance import all_current, checkout_fingerprint, git_sha
from harness.tracking.store import display_uri


def _short(sha: str) -> str:
    """A commit as people quote it: twelve hex digits, ``-dirty`` kept."""
    return sha[:12] + ("-dirty" if sha.endswith("-dirty") else "")


def check_command(name: str, out: Path) -> str:
    """The ``study check`` that compares runs with this report: a study named by its file's path
    has no ``reports/<name>`` of the project's, so the command names this report's runs.csv."""
    ref = study_ref(name)
    return f"study check {ref}" + (f" --reference {out / 'runs.csv'}" if ref != name else "")


def study_page(data: ReportData, out: Path, main: sections.TablesSection, extra: list[sections.Section],
               figures: list[tuple[str, Path]], diags: list[tuple[str, str, int, list[Path]]]) -> str:
    """The study's ``index.md``: question, how to reproduce, the sections, plots, diagnostics,
    config hashes and where the runs are tracked."""
    study, df = data.study, data.df
    prof = study.profile(data.sel.profile)
    c = aggregate.counts(df)
    cmds = data.invocations()
    hashes = sorted({r for r in df.config_hash})
    git = data.code_versions()
    made_from = committed.source_text(data)  # "" unless from the committed runs.csv
    lines = [
        f"# Study `{study.name}` ({data.sel.profile} profile)",
        "",
        *stale_lines(data),
        f"**Question.** {study.question}",
        "",
    ]
    if study.notes:
        lines += [f"**Notes.** {study.notes}", ""]
    lines += [
        f"Runs: {c['n_runs']} planned {_grid(c['n_runs'], df)}; {c['n_finished']} finished, {c['n_failed']} failed"
        f" ({c['n_diverged']} diverged), {c['n_missing'] + c['n_running']} missing."
        f" Baseline: `{prof.baseline}`. Expected runtime: {currency.expected(c['n_runs'], data.sel.profile, prof, prof.jobs)}.",
        "",
        "## Reproduce",
        "",
        "```sh",
        command_line(study.name, data.sel),
        f"study report {study_ref(study.name)}",
        "```",
        "",
    ]
    if cmds:
        lines += ["Invocations that produced these runs:", "", *[f"- `{cmd}`" for cmd in cmds], ""]
    if len(df) and "command" in df:
        first = df.iloc[0]
        lines += [f"One run by hand, without the harness ({first.variant} / {first.scene} / seed {first.seed}; the"
                  f" `command` column of [runs.csv](runs.csv) has every run's), and `{check_command(study.name, out)}`"
                  " compares a study's runs with this report's, bit for bit:", "",
                  "```sh", str(first.command).replace(" && ", " &&\n"), "```", ""]
    lines += sections.determinism_lines(df)
    for section in extra:
        lines += [f"## {section.title}", "", section.md, ""]
    lines += ["## Tables", "",
              "Full tables, t-tests and failures: [table.md](table.md); LaTeX: [table.tex](table.tex);",
              "per-run data: [runs.csv](runs.csv), per-cell statistics: [summary.csv](summary.csv).", ""]
    if main.tables:
        lines += [f"### {main.tables[0].title}", "", tables.to_markdown(main.tables[0]), ""]
    if "speed_accuracy" in study.plots and df.scene.nunique() > 1:
        lines += [speed_accuracy_text.report_markdown(df), "",
                  "Per scene and variant: [speed_accuracy.csv](speed_accuracy.csv); the chosen budgets:"
                  " [speed_accuracy_smallest.csv](speed_accuracy_smallest.csv).", ""]
        if "psnr_cc" in df and df["psnr_cc"].notna().any():
            lines += [speed_accuracy_text.colour_aligned_markdown(df), ""]
        if methods := speed_accuracy_text.method_markdown(df, data.baseline):
            lines += [methods, ""]
    elif "speed_accuracy" in study.plots:
        sa = aggregate.speed_accuracy(df)
        chosen = aggregate.smallest_within(sa)
        if chosen is not None and sa.budget.nunique() > 1:  # a budget sweep (not e.g. a learning-rate one)
            lines += [f"**Smallest budget within {aggregate.size_tolerance():g} dB (the SESOI) of the best:**"
                      f" `{chosen['variant']}` — budget"
                      f" {int(chosen['budget'])} Gaussians, {int(chosen['iterations'])} iterations,"
                      f" PSNR {chosen['mean']:.2f} dB, {chosen['train_seconds']:.1f} s of training.", ""]
    if figures:
        lines += ["## Plots", ""]
        for caption, p in figures:
            lines += [f"### {caption}", "", f"![{caption}]({p.relative_to(out).as_posix()})", ""]
    if diags:
        lines += ["## Diagnostics", "",
                  "Logged by the runs under the `diagnostics/` artifact path (lowest finished seed with figures).", ""]
        for v, s, seed, paths in diags:
            lines += [f"### {v} / {s} (seed {seed})", ""]
            lines += [_embed(p, out) for p in paths] + [""]
    if gone := committed.missing_diagnostics(data.recorded):
        lines += [f"Not shown: the diagnostics of {', '.join(gone)}, which the committed report's page showed but"
                  " its folder does not hold (they are artifacts of the runs in the store that made them).", ""]
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
        f"MLflow store `{display_uri(data.uri)}`, experiment `{data.experiment}`; code at {', '.join(git) or 'unknown'};"
        f" trainer fingerprint {', '.join(f'`{f}`' for f in data.trainer_fingerprints()) or 'none'}"
        f" (this checkout: `{checkout_fingerprint()}`).{committed.filled_text(data)}",
        f"Parent runs: {', '.join(data.parent_ids()) or 'none'}. Browse them with:",
        "",
        "```sh",
        browse_command(data.uri),
        "```",
        "",
        f"_Generated by `study report {study_ref(study.name)}`{made_from} on {time.strftime('%Y-%m-%d %H:%M')}"
        f" with the harness at {_short(git_sha())}._",
        "",
    ]
    return "\n".join(lines)


def stale_lines(data: ReportData) -> list[str]:
    """The page's first lines when its runs were not all made by this checkout's trainer
    (``report.currency``): who made them, the command that refreshes them and its time here."""
    current = checkout_fingerprint()
    made_by = data.trainer_fingerprints()
    if not made_by or all_current(made_by, current):
        return []
    name, prof = data.study.name, data.study.profile(data.sel.profile)
    refresh = f"{command_line(name, data.sel)} --rerun-stale && study report {name}"
    runs = currency.to_do(data.df, current)
    return currency.stale_note(made_by, current, refresh, runs,
                               currency.expected(runs, data.sel.profile, prof, prof.jobs))


def _grid(n_runs: int, df: pd.DataFrame) -> str:
    """How the planned runs split: the full product when every variant runs every scene and
    seed, else the counts (scenes with their own variants or seeds)."""
    v, sc, se = df.variant.nunique(), df.scene.nunique(), df.seed.nunique()
    if n_runs == v * sc * se:
        return f"= {v} variants × {sc} scenes × {se} seeds"
    drawn = ""
    if "instance" in df and (df.instance > 0).any():  # spec.instances: a scene and its fresh draws
        sc = df.instance_of.nunique()
        k = df[df.instance > 0].groupby("instance_of").instance.nunique()
        each = (f"{plural(int(k.iloc[0]), 'fresh instance')} of each" if k.nunique() == 1
                else f"{plural(int(k.sum()), 'fresh instance')} of {len(k)} of them")
        drawn = f" ({each}, one seed an instance)"
    return (f"over {v} variants, {sc} scenes{drawn} and {se} seeds (not every variant on every scene and seed)")


FINGERPRINT = ".fingerprint"  # what a report was made from: its runs and the code that wrote it


def fingerprint(df: pd.DataFrame, decided: pd.DataFrame | None = None) -> str:
    """A hash of the planned runs (run id, status, every metric), of the study's claims as the
    decision over every study left them (``decided``: a run of another study can move this page's
    corrected p-values) and of the harness code version: equal fingerprints mean the report would
    come out the same."""
    from harness.tracking.provenance import git_sha

    cols = sorted(c for c in df.columns if c not in ("scene_label",))
    blob = df[cols].sort_values(["variant", "scene", "seed"]).to_csv(index=False) + git_sha()
    if decided is not None:
        blob += decided.to_csv(index=False)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def write_report(name: str, sel: Selection | None = None, *, studies_dir: Path | None = None,
                 reports_root: Path = USER_REPORTS, echo: Callable[[str], None] = print,
                 if_changed: bool = False, skip_empty: bool = False) -> Path | None:
    """Write ``<reports_root>/<name>/`` and return its index path. ``if_changed``: leave the report
    as it is when its runs and the code are those it was made from (``.fingerprint``). A study
    without finished runs in the store is reported from its committed runs
    (``committed.from_committed``: ``reports/NAME/runs.csv``), else writes nothing: ``InputError``;
    with ``skip_empty`` (``--all``) it writes nothing and returns None."""
    data = collect(name, sel, studies_dir)
    if not (data.df.status == "FINISHED").any():
        if skip_empty:
            echo(f"{name}: no finished runs, no report")
            return None
        data = committed.from_committed(data, COMMITTED_REPORTS / name, echo)  # else InputError
    else:
        data = committed.fill_missing(data, COMMITTED_REPORTS / name, echo)
    out = Path(reports_root) / name
    # a whole profile asked for (`study report --all --profile quick`, as `make reports`): every
    # study's verdicts over that profile's runs, not over whatever subset each last ran
    whole = sel is not None and not (sel.seeds or sel.scenes or sel.variants or sel.overrides)
    family_profile = sel.profile if whole else None
    decided = families.study_frame(name, out.parent, profile=family_profile) if data.study.claims else None
    stamp = fingerprint(data.df, decided)
    if if_changed and (out / FINGERPRINT).is_file() and (out / FINGERPRINT).read_text().strip() == stamp:
        echo(f"{name}: report up to date ({out / 'index.md'})")
        return out / "index.md"
    out.mkdir(parents=True, exist_ok=True)
    data.df.to_csv(out / "runs.csv", index=False)
    main = sections.tables_section(data)
    extra = [s for s in (sections.claims_section(data, out, decided, family_profile),
                         sections.variance_section(data, out),
                         sections.ladders_section(data, out)) if s is not None]
    (out / "table.md").write_text(main.md + "".join(f"\n## {s.title}\n\n{s.md}\n" for s in extra))
    (out / "table.tex").write_text(main.tex + "".join(f"\n{s.tex}\n" for s in extra if s.tex))
    if main.summaries:
        pd.concat(main.summaries.values(), ignore_index=True).to_csv(out / "summary.csv", index=False)
    figures = sections.figures(data, out) + xt_figures.figures(data, out)
    if data.recorded is None:  # from the store: the diagnostics are this report's alone (none stale);
        _clear_diagnostics(out / "diagnostics", committed.kept_diagnostics(data, out))  # from committed: the source
    diags = sections.diagnostics(data, out)
    (out / "index.md").write_text(study_page(data, out, main, extra, figures, diags))
    (out / FINGERPRINT).write_text(stamp + "\n")
    c = aggregate.counts(data.df)
    echo(f"{name}: report of {c['n_runs']} runs ({c['n_finished']} finished, {c['n_failed']} failed,"
         f" {c['n_missing'] + c['n_running']} missing) written to {out / 'index.md'}")
    mlflow_answer.log_answer(data, out, echo)  # the verdicts and means on the reported parent run
    return out / "index.md"


def _clear_diagnostics(folder: Path, keep: set[tuple[str, str]]) -> None:
    """Remove ``folder`` (``<variant>/<scene>/`` diagnostics) but the cells in ``keep``: those of runs
    read from the committed report, whose files there are their source."""
    if not keep:
        shutil.rmtree(folder, ignore_errors=True)
        return
    for cell in sorted(p for p in folder.glob("*/*") if p.is_dir()):
        if (cell.parent.name, cell.name) not in keep:
            shutil.rmtree(cell)
    for variant in [p for p in folder.glob("*") if p.is_dir() and not any(p.iterdir())]:
        variant.rmdir()


def _embed(path: Path, root: Path) -> str:
    """Markdown for one diagnostic file: images inline, anything else (JSON numbers) as a link."""
    rel = path.relative_to(root).as_posix()
    if path.suffix.lower() in {".png", ".jpg", ".jpeg", ".svg"}:
        return f"![{path.name}]({rel})"
    return f"[{path.name}]({rel})"
