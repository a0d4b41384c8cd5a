"""A study's report from its committed runs, for a checkout whose tracking store has none of them.

``study report NAME`` reads the study's runs from the tracking store; when the store has no
finished run of the reported selection, ``from_committed`` reads them from the committed report
instead (``reports/NAME/runs.csv``, floats exactly as written) and everything its page recorded
beyond that file (``Recorded``): the code version, MLflow store, experiment, parent runs and
invocations (its "Tracking" section) and which seed's diagnostics it shows. Diagnostic figures
are artifacts of the runs in the store that made them, so ``diagnostics`` reuses the committed
report's ``diagnostics/`` files; a cell whose files are not there is named on the page and on
the console. From the same runs and the same harness the page comes out as committed, but
for its last line, which says when, and that it was made from the committed runs.
"""

from __future__ import annotations

import dataclasses
import fnmatch
import re
import shutil
from pathlib import Path
from typing import Callable

import pandas as pd

from ftgspp.errors import InputError
from harness.analysis.aggregate import DOMAIN_COLUMNS, KEY_COLUMNS, RUN_COLUMNS
from harness.analysis.reproduction import answered, read_reference
from harness.report.results import Filled, Recorded, ReportData, trainer_fingerprints
from harness.spec.instances import instance_columns
from harness.spec.metrics import add_differences
from harness.spec.runs import command_line
from harness.tracking.provenance import same_bits
from harness.tracking.store import display_uri

TRACKING = re.compile(r"^MLflow store `([^`]*)`, experiment `([^`]*)`; code at (.*?); trainer fingerprint", re.M)
PARENTS = re.compile(r"^Parent runs: (.*)\. Browse them with:$", re.M)
INVOCATIONS = re.compile(r"^Invocations that produced these runs:\n\n((?:- `.*`\n)+)", re.M)
DIAGNOSTIC = re.compile(r"^### (.+) / (.+) \(seed (\d+)\)$", re.M)


def read_recorded(folder: Path) -> Recorded:
    """What the committed page ``folder/index.md`` names of its runs (empty fields without one)."""
    page = (folder / "index.md").read_text() if (folder / "index.md").is_file() else ""
    tracking, parents = TRACKING.search(page), PARENTS.search(page)
    code = tracking.group(3).split(", ") if tracking and tracking.group(3) != "unknown" else []
    ids = parents.group(1).split(", ") if parents and parents.group(1) != "none" else []
    invocations = INVOCATIONS.search(page)
    commands = [line[3:-1] for line in invocations.group(1).splitlines()] if invocations else []
    seeds = [(v, s, int(seed)) for v, s, seed in DIAGNOSTIC.findall(page.partition("\n## Diagnostics\n")[2])]
    return Recorded(folder, code=tuple(code), uri=tracking.group(1) if tracking else "",
                    experiment=tracking.group(2) if tracking else "", parents=tuple(ids),
                    invocations=tuple(commands), diagnostic_seeds=tuple(seeds))


def read_runs(path: Path) -> pd.DataFrame:
    """A committed ``runs.csv`` as the per-run frame ``report.results`` builds: provenance as
    text, empty text cells empty (not NaN) except a missing run's domain."""
    df = read_reference(str(path))
    for col in [c for c in RUN_COLUMNS if c in df]:
        df[col] = df[col].astype(object).fillna("").astype(str)
    ran = df.status != "MISSING"
    for col in [c for c in DOMAIN_COLUMNS if c in df]:
        df[col] = df[col].astype(object)
        df.loc[ran, col] = df.loc[ran, col].fillna("")
    return df


def from_committed(data: ReportData, folder: Path, echo: Callable[[str], None] = print) -> ReportData:
    """``data`` (a selection the store has no finished run of) with its runs read from the
    committed report in ``folder``: the planned runs it holds, the rest missing.
    ``InputError`` when it holds none of them."""
    name, path = data.study.name, folder / "runs.csv"
    where = f"no finished runs in {data.experiment} at {display_uri(data.uri)}"
    if not path.is_file():
        raise InputError(f"study report {name}", f"{where}, and no committed runs ({path}) to report from"
                                                 f" (run them first: {command_line(name, data.sel)}); nothing written")
    runs = read_runs(path)
    planned = {key: i for i, key in enumerate(p.key for p in data.planned)}
    order = [planned.get(key) for key in runs[KEY_COLUMNS].itertuples(index=False, name=None)]
    runs = runs.assign(_order=order)[[i is not None for i in order]]
    if runs.empty:
        raise InputError(f"study report {name}", f"{where}, and {path} holds none of the {len(planned)} runs"
                                                 f" of {command_line(name, data.sel)} (another profile, or the study's"
                                                 " configs changed since: other config hashes); nothing written")
    missing = data.df.assign(_order=range(len(data.df)))  # row i is planned run i (results.runs_frame)
    missing = missing[~missing._order.isin(set(runs._order))]
    # the scene instances from the study file (spec.instances): a runs.csv may predate the columns
    df = add_differences(instance_columns(pd.concat([runs, missing]) if len(missing) else runs, data.study))
    df = df.sort_values("_order", kind="stable").drop(columns="_order").reset_index(drop=True)
    recorded = read_recorded(folder)
    lacks = _lacking(recorded)
    data = dataclasses.replace(data, df=df, uri=recorded.uri, experiment=recorded.experiment, parents=[],
                               store=None, chosen={}, recorded=recorded)
    echo(f"{name}: the tracking store has none of its runs; reporting from the committed runs of"
         f" {', '.join(c[:7] for c in recorded.code) or 'unknown code'} ({path}"
         + (f"; {len(missing)} of its {len(planned)} planned runs are not in it" if len(missing) else "") + ")")
    if lacks:
        echo(f"{name}: not in the committed report, so not on the page: {'; '.join(lacks)}")
    return data


def fill_missing(data: ReportData, folder: Path, echo: Callable[[str], None] = print) -> ReportData:
    """``data`` read from the tracking store, with each planned run the store lacks (MISSING) that
    the committed report in ``folder`` holds finished (or diverged: ``reproduction.answered``, as
    ``currency`` reads it), by the trainer of the store's finished runs
    or one recorded to train its bits (``tracking.provenance.same_bits``), in a determinism domain
    of theirs (``ftgspp.runtime.determinism``: same machine kind, mode and threads), read from that
    report (``Filled``): the same config hash, trainer bits and domain give the same run (``study
    check`` proves it of the runs both hold), so neither arm of a comparison carries another
    machine's numbers. A run the store
    holds in any state, or the file holds by another trainer, stays as the store has it. The rows
    keep the commit and start time they were made at, which registration reads. ``data`` itself
    when nothing is filled."""
    path = folder / "runs.csv"
    df = data.df
    lacking = df.status == "MISSING"
    if data.recorded is not None or not lacking.any() or not (df.status == "FINISHED").any() or not path.is_file():
        return data
    same = set().union(*(same_bits(f) for f in set(trainer_fingerprints(df)) - {"unrecorded"}))
    domains = set(df.loc[df.status == "FINISHED", "domain"].astype(str)) - {""} if "domain" in df else set()
    runs = read_runs(path)
    if not {"trainer_fingerprint", "git_sha", "domain"} <= set(runs.columns):
        return data  # a file older than the provenance columns cannot show it holds the same runs
    runs = runs[answered(runs) & runs.trainer_fingerprint.isin(same) & runs.domain.isin(domains)]
    held = {key: i for i, key in enumerate(runs[KEY_COLUMNS].itertuples(index=False, name=None))}
    keys = [key if want and key in held else None
            for key, want in zip(df[KEY_COLUMNS].itertuples(index=False, name=None), lacking)]
    filled = [k for k in keys if k is not None]
    if not filled:
        return data
    rows = runs.iloc[[held[k] for k in filled]].assign(_order=[i for i, k in enumerate(keys) if k is not None])
    rest = df.assign(_order=range(len(df)))[[k is None for k in keys]]
    out = add_differences(instance_columns(pd.concat([rest, rows]), data.study))
    out = out.sort_values("_order", kind="stable").drop(columns="_order").reset_index(drop=True)
    code = tuple(sorted(set(rows.git_sha.astype(str)) - {""}))
    echo(f"{data.study.name}: {len(filled)} of its {len(df)} planned runs, which the tracking store lacks, read from"
         f" the committed report ({path}; made at {', '.join(c[:7] for c in code) or 'unknown code'}, by the store's"
         f" trainer or one recorded to train its bits, in its determinism domain)")
    return dataclasses.replace(data, df=out, filled=Filled(folder, frozenset(filled), code))


def filled_text(data: ReportData) -> str:
    """The page's sentence on the runs read from the committed report (``fill_missing``), else ""."""
    if data.filled is None:
        return ""
    n = len(data.filled.keys)
    return (f" {n} {'run' if n == 1 else 'runs'} of the plan, which the store lacks, {'is' if n == 1 else 'are'}"
            f" read from the committed report (`{(data.filled.folder / 'runs.csv').as_posix()}`), made at"
            f" {', '.join(c[:7] for c in data.filled.code) or 'unknown code'} by the store's trainer or one recorded"
            " to train its bits (`harness/tracking/same_bits.yaml`), in its determinism domain; their diagnostics"
            " and figures are that report's.")


def filled_diagnostics(data: ReportData, out: Path, cells: set[tuple[str, str]]) -> list[tuple[str, str, int, list[Path]]]:
    """``diagnostics`` of ``cells``, those whose finished runs all come from the committed report
    (``filled_cells``): that report's files, with the seed its page named."""
    if not cells:
        return []
    done = data.df[data.df.status == "FINISHED"]
    only = done[[cell in cells for cell in zip(done.variant, done.scene)]]
    return diagnostics(dataclasses.replace(data, df=only, recorded=read_recorded(data.filled.folder)), out)


def filled_rows(data: ReportData) -> pd.Series:
    """Which rows of ``data.df`` were read from the committed report (``fill_missing``)."""
    if data.filled is None:
        return pd.Series(False, index=data.df.index, dtype=bool)
    keys = data.filled.keys
    return pd.Series([k in keys for k in data.df[KEY_COLUMNS].itertuples(index=False, name=None)],
                     index=data.df.index, dtype=bool)


def filled_cells(data: ReportData) -> set[tuple[str, str]]:
    """(variant, scene) cells whose finished runs all come from the committed report."""
    if data.filled is None:
        return set()
    done = data.df[data.df.status == "FINISHED"]
    mask = filled_rows(data)[done.index]
    return {cell for cell, sub in done.groupby(["variant", "scene"], sort=False).groups.items() if mask[sub].all()}


def kept_diagnostics(data: ReportData, out: Path) -> set[tuple[str, str]]:
    """The cells of ``out/diagnostics`` a report from the store must not clear: those of runs read
    from the committed report when ``out`` is that report's folder (its files are their source)."""
    if data.filled is None or (out / "diagnostics").resolve() != (data.filled.folder / "diagnostics").resolve():
        return set()
    return filled_cells(data)


def missing_diagnostics(recorded: Recorded | None) -> list[str]:
    """``variant / scene`` cells whose diagnostics the committed page showed but its folder lacks."""
    if recorded is None:
        return []
    folder = recorded.folder / "diagnostics"
    return [f"{v} / {s}" for v, s, _ in recorded.diagnostic_seeds if not (folder / v / s).is_dir()]


def _lacking(recorded: Recorded) -> list[str]:
    """What the committed report does not hold of what its page showed or named."""
    out = []
    if not (recorded.folder / "index.md").is_file():
        out.append(f"its page ({recorded.folder / 'index.md'}: the store, parent runs and invocations that made the"
                   " runs, and which seeds' diagnostics it showed)")
    if gone := missing_diagnostics(recorded):
        out.append(f"the diagnostics of {', '.join(gone)} (artifacts of the runs in the store that made them)")
    return out


def source_text(data: ReportData) -> str:
    """`` from the committed runs of <code> (<runs.csv>)`` for a page made from them, else ""."""
    if data.recorded is None:
        return ""
    code = ", ".join(c[:7] for c in data.recorded.code) or "unknown code"
    return f" from the committed runs of {code} ({(data.recorded.folder / 'runs.csv').as_posix()})"


def _files(folder: Path) -> list[Path]:
    """Every file under ``folder``, each folder's entries by name, subfolders in place (the order
    the tracking store lists a run's artifacts in)."""
    out: list[Path] = []
    for p in sorted(folder.iterdir(), key=lambda p: p.name):
        out.extend(_files(p) if p.is_dir() else [p])
    return out


def diagnostics(data: ReportData, out: Path) -> list[tuple[str, str, int, list[Path]]]:
    """``sections.diagnostics`` for a report from committed runs: the committed report's
    ``diagnostics/<variant>/<scene>/`` files (copied into ``out`` unless they are there), per
    cell in the order the store's runs give, with the seed its page named (else the lowest
    finished one)."""
    assert data.recorded is not None
    src = data.recorded.folder / "diagnostics"
    patterns = list(data.study.diagnostics)
    if not patterns:
        return []
    seeds = {(v, s): seed for v, s, seed in data.recorded.diagnostic_seeds}
    got = []
    ok = data.df[data.df.status == "FINISHED"].sort_values("seed")
    for (v, s), sub in ok.groupby(["variant", "scene"], sort=False):
        folder = src / v / s
        if not folder.is_dir():
            continue
        files = [p for p in _files(folder) if any(fnmatch.fnmatch(p.name, pat) for pat in patterns)]
        target = out / "diagnostics" / v / s
        copies = [target / p.relative_to(folder) for p in files]
        if target.resolve() != folder.resolve():  # else --out is the committed root: they are there
            for p, copy in zip(files, copies):
                copy.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(p, copy)
        if files:
            got.append((v, s, seeds.get((v, s), int(sub.seed.iloc[0])), copies))
    return got
