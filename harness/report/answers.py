"""The brief's three questions, answered in one sentence each from the committed reports' tables.

- ``speed_sentence``: what FreeTimeGS++ costs and buys against FreeTimeGS at the grid's
  reference cell (``speed_accuracy/method_comparison.csv``);
- ``size_sentence``: the smallest budget within the SESOI (0.2 dB) of each method's best per scene
  (``speed_accuracy/speed_accuracy_smallest.csv``) and the budget finder's answer on the scene of
  known size (``budget/budget_known_size/budget.csv``);
- ``stability_sentence``: where each method first breaks along the stability ladders, and on
  how many ladders it loses quality (``stability/ladders.csv``).

Each returns "" when its table is missing; ``answers_markdown`` lists the ones there are. The index
puts them above its figures; FINDINGS.md cites the same numbers.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import pandas as pd

from harness.analysis.aggregate import size_tolerance
from harness.report.speed_accuracy_text import unsaturated

REFERENCE_CELL = (5000.0, 3000.0)  # the quick profile's budget and iterations
KNOWN_SIZE = Path("budget") / "budget_known_size" / "budget.csv"


def _read(path: Path) -> pd.DataFrame:
    return pd.read_csv(path) if path.is_file() else pd.DataFrame()


def _span(values: pd.Series, fmt: str) -> str:
    lo, hi = float(values.min()), float(values.max())
    return format(lo, fmt) if lo == hi else f"{format(lo, fmt)} to {format(hi, fmt)}"


def _resolved(ref: pd.DataFrame, m: str) -> str:
    """``, 1 of 4 scenes' 95% intervals excluding 0``: how many differences the runs resolve."""
    low, high = ref.get(f"d_{m}_low"), ref.get(f"d_{m}_high")
    if low is None or high is None:
        return ""
    k = int(((low > 0) | (high < 0)).sum())
    return f" ({k} of {len(ref)} scenes' 95% intervals exclude 0)"


def speed_sentence(root: Path) -> str:
    """What the second method costs and buys against the first at ``REFERENCE_CELL`` (every
    cell when the grid lacks it): the span over scenes of each difference and ratio."""
    cmp = _read(root / "speed_accuracy" / "method_comparison.csv")
    if cmp.empty:
        return ""
    ref = cmp[(cmp.budget == REFERENCE_CELL[0]) & (cmp.iterations == REFERENCE_CELL[1])]
    where = f"at {REFERENCE_CELL[0]:,.0f} Gaussians and {REFERENCE_CELL[1]:,.0f} iterations"
    if ref.empty:
        ref, where = cmp, "over every cell of the grid"
    first, second = ref["first"].iloc[0], ref["second"].iloc[0]
    # raw PSNR first: the paper's metric, and the one colour correction is for; colour-aligned PSNR
    # (which removes by construction what colour correction does) beside it
    parts = [f"PSNR {_span(ref.d_psnr, '+.2f')} dB{_resolved(ref, 'psnr')}",
             f"colour-aligned PSNR {_span(ref.d_psnr_cc, '+.2f')} dB{_resolved(ref, 'psnr_cc')}",
             f"training time ×{_span(ref.r_train_seconds, '.2f')}"]
    if ref.r_render_fps_1thread.notna().any():
        parts.append(f"render FPS at one thread ×{_span(ref.r_render_fps_1thread.dropna(), '.2f')}")
    if ref.r_model_bytes.notna().any():
        parts.append(f"model size ×{_span(ref.r_model_bytes.dropna(), '.2f')}")
    return (f"**Speed against accuracy:** {where}, `{second}` against `{first}` over {ref.scene_label.nunique()}"
            " scenes: " + ", ".join(parts) + " (per scene and cell: speed_accuracy/index.md).")


def _needs(r: pd.Series, runs: pd.DataFrame | None = None, metric: str = "psnr_cc") -> str:
    """``static 5,000``; ``≥ 20,000 (no saturation)`` when the largest budget is the best, with the
    runs per budget that would settle the grid's last doubling when ``runs`` (the grid's runs.csv)
    are given (``grid_runs_needed``); ``(its best: more scores lower)`` when a smaller budget is the
    best outright."""
    if unsaturated(r):
        need = grid_runs_needed(runs, r, metric) if runs is not None else math.nan
        said = (f"; {need:,.0f} runs a budget would settle its last doubling" if math.isfinite(need) else
                "; more runs than the power search tries would settle it" if need == math.inf else "")
        return f"{r.scene_label} ≥ {r.budget:,.0f} (no saturation{said})"
    if r.variant == r.best_variant:
        return f"{r.scene_label} {r.budget:,.0f} (its best: more Gaussians score lower)"
    unsettled = pd.isna(r.gap_ci_includes_tol) or str(r.gap_ci_includes_tol) == "True"
    return f"{r.scene_label} {r.budget:,.0f}" + (" (not settled)" if unsettled and r.variant != r.best_variant else "")


def grid_runs_needed(runs: pd.DataFrame, r: pd.Series, metric: str) -> float:
    """Runs per budget that would settle, for ``r``'s scene, method and iterations, the grid's last
    doubling (its largest budget against half of it) inside ±SESOI: the budget finder's rule
    (``budget_search.runs_needed`` at the two budgets' pooled SD); NaN when the grid has no such
    doubling or ``metric``."""
    from harness.analysis.budget_search import pooled_sd, runs_needed
    from harness.analysis.speed_accuracy_scenes import method_of

    if runs.empty or not {metric, "budget", "iterations", "scene", "variant"} <= set(runs):
        return math.nan
    cell = runs[(runs.scene == r.scene) & (runs.iterations == r.iterations)
                & (runs.variant.map(method_of) == r.get("method", ""))]
    if "status" in cell:
        cell = cell[cell.status == "FINISHED"]
    top = cell.budget.max()
    values = [cell.loc[cell.budget == b, metric].dropna().to_numpy(float) for b in (top / 2, top)]
    if any(len(v) < 2 for v in values):
        return math.nan
    return runs_needed(size_tolerance(), pooled_sd(*values))


def _known_size_page(root: Path) -> pd.DataFrame:
    """The known-size scene's search: the noisy scene's (``budget_known_size_noise*``, whose PSNR
    has a ceiling) when there is one, else the noise-free one's."""
    for page in [*sorted((root / "budget").glob("budget_known_size_noise*/budget.csv")), root / KNOWN_SIZE]:
        found = _read(page)
        if {"chosen", "true_size", "saturated"} <= set(found):  # a page from before these columns: none
            return found
    return pd.DataFrame()


def _search(found: pd.DataFrame) -> str:
    """``5,000 (4,012 drawn; 0.29 MB; gap to the best +0.05 [−0.10, +0.15] dB)`` for a budget page's
    chosen row (what the page has of it), or ``≥ …`` and why it did not settle."""
    row = found[found.chosen].iloc[0]
    details = []
    if pd.notna(row.get("n_alive", float("nan"))):
        details.append(f"{row.n_alive:,.0f} drawn")
    if pd.notna(row.get("model_bytes", float("nan"))):
        details.append(f"{row.model_bytes / 1e6:.2f} MB")
    if not bool(row.get("best", True)) and pd.notna(row.get("gap_high", float("nan"))):
        details.append(f"gap to the best {row.gap_mean:+.2f} [{row.gap_low:+.2f}, {row.gap_high:+.2f}] dB")
    if not bool(found.saturated.iloc[0]):  # doubling reached the cap without a settled gain
        need = found.runs_needed.iloc[0] if "runs_needed" in found else float("nan")
        details.insert(0, "not saturated at the cap" + (f"; {need:,.0f} runs a budget would settle it"
                                                         if pd.notna(need) and need != float("inf") else ""))
        return f"≥ {row.budget:,.0f} Gaussians ({'; '.join(details)})"
    if "settled" in found and not bool(found.settled.iloc[0]):
        details.insert(0, "not settled within the SESOI")
    return f"{row.budget:,.0f} Gaussians" + (f" ({'; '.join(details)})" if details else "")


def size_sentence(root: Path) -> str:
    """Per method, each scene's smallest budget within the SESOI (0.2 dB) of that method's best
    colour-aligned PSNR on the grid (raw PSNR for a report without it: the held-out camera's
    colour, which no budget learns, flattens the raw one), or that it does not saturate; then the
    budget finder's answers (``study budget``): the known-size scene's (as a multiple of the K that
    drew it, beside the control started from the true Gaussians) and the textured scenes'."""
    aligned = _read(root / "speed_accuracy" / "speed_accuracy_smallest_psnr_cc.csv")
    chosen = aligned if not aligned.empty else _read(root / "speed_accuracy" / "speed_accuracy_smallest.csv")
    metric = "colour-aligned PSNR" if not aligned.empty else "raw PSNR"
    grid = _read(root / "speed_accuracy" / "runs.csv")
    parts = []
    if not chosen.empty:
        method = chosen["method"].fillna("") if "method" in chosen else pd.Series([""] * len(chosen))
        for m, sub in chosen.groupby(method, sort=False):
            parts.append((f"`{m}`: " if m else "") + ", ".join(
                _needs(r, grid, "psnr_cc" if not aligned.empty else "psnr") for _, r in sub.iterrows()))
    text = ""
    if parts:
        text = (f"**The smallest sufficient model** (within the SESOI, {size_tolerance():g} dB, of the best {metric}"
                f" on the grid up to {chosen.largest_budget.max():,.0f} Gaussians): " + "; ".join(parts) + ".")
    known = _known_size_page(root)
    if not known.empty and known.chosen.any():
        row = known[known.chosen].iloc[0]
        k = known.true_size.iloc[0]
        ratio = "" if math.isnan(k) else f", {row.budget / k:.2f}× the K = {k:,.0f} that drew it"
        control = known.control_mean.iloc[0] if "control_mean" in known else float("nan")
        started = "" if pd.isna(control) else f"; started from the true Gaussians at K: {control:.2f} dB"
        text += f" On the scene of known size the budget finder answers {_search(known)}{ratio}{started}."
    searches = []
    for page in sorted((root / "budget").glob("budget_*/budget.csv")):
        found = _read(page)
        if page.parent.name.startswith(KNOWN_SIZE.parent.name) or "chosen" not in found or not found.chosen.any():
            continue
        searches.append(f"{page.parent.name.removeprefix('budget_')} {_search(found)}")
    if searches:
        text += (" `study budget` (FreeTimeGS, 3 seeds a budget; doubling until a doubling's gain is settled inside"
                 " the SESOI, then the smallest budget whose gap to the best is settled below it): "
                 + ", ".join(searches) + ".")
    pruned = [_pruning(page) for page in sorted((root / "pruning").glob("*/settled.csv"))]
    if pruned:
        text += " Pruning by significance (`study prune`, then a recovery fine-tune): " + "; ".join(pruned) + "."
    compared = [search_against_pruning(scene, search, page) for scene, search, page in _search_and_pruning(root)]
    if compared:
        text += " Budget search against pruning, FreeTimeGS, per scene: " + "; ".join(compared) + "."
    return text.strip()


_PRUNED_FROM = re.compile(r"_(?P<method>[a-z0-9]+)_b\d+k?_i\d+k?_(?P<scene>[A-Za-z0-9_]+)$")


def _search_and_pruning(root: Path) -> list[tuple[str, pd.DataFrame, pd.DataFrame]]:
    """(scene, its ``study budget`` page, a FreeTimeGS pruning page of it) for every scene that has
    both: the budget finder trains FreeTimeGS, so only FreeTimeGS's pruning answers the same question."""
    found = []
    for page in sorted((root / "pruning").glob("*/settled.csv")):
        m = _PRUNED_FROM.search(page.parent.name)
        search = root / "budget" / f"budget_{m.group('scene')}" / "budget.csv" if m else None
        if m and m.group("method") == "ftgs" and search.is_file():
            found.append((m.group("scene"), _read(search), _read(page)))
    return found


def search_against_pruning(scene: str, search: pd.DataFrame, pruned: pd.DataFrame) -> str:
    """One scene's smallest model by the two routes, against the budget search's best mean PSNR: the
    search's chosen budget (settled or not), the fewest Gaussians pruning keeps with a mean within
    the SESOI of that best (settled when its paired loss to the unpruned model is), and which route
    gives the answer: the smaller settled one, else "neither settles"."""
    sesoi = float(search.sesoi.iloc[0])
    best = search.loc[search.psnr_mean.idxmax()]
    row = search[search.chosen].iloc[0]
    search_settled = bool(search.saturated.iloc[0]) and bool(search.settled.iloc[0])
    head = (f"{scene}: the search's best {best.psnr_mean:.2f} dB at {best.budget:,.0f}, its answer "
            + (f"{row.budget:,.0f}" if search_settled else f"≥ {row.budget:,.0f} (not settled)"))
    close = pruned[(pruned.keep < 1) & (pruned.psnr >= best.psnr_mean - sesoi)].sort_values("n_gaussians")
    if close.empty:
        return head + f"; no pruned model within {sesoi:g} dB of that best: the search gives the answer"
    p = close.iloc[0]
    is_settled = close.settled.map(lambda v: bool(v) if pd.notna(v) else False)
    base = pruned[pruned.keep == 1].iloc[0]
    text = (f"{head}; pruning {base.n_gaussians:,.0f} → {p.n_gaussians:,.0f} keeps {p.psnr:.2f} dB"
            f" ({'settled' if is_settled.iloc[0] else 'not settled'} against the unpruned model with {int(p.n)}"
            f" seeds: loss [{p.loss_low:+.2f}, {p.loss_high:+.2f}] dB)")
    routes = [(row.budget, "the search")] if search_settled else []
    if is_settled.any():  # the fewest kept that is both close to the best and settled
        routes.append((close[is_settled].n_gaussians.min(), "pruning"))
    if not routes:
        return text + "; neither settles" + (", pruning gives the smaller model at the same mean"
                                              if p.n_gaussians < row.budget else "")
    n, route = min(routes)
    return text + f"; the answer, {n:,.0f} Gaussians, comes from {route}"


def _pruning(page: Path) -> str:
    """One page of ``study prune``: its unpruned model, the smallest fraction settled within the
    SESOI of it (paired by seed), or that none is."""
    table = _read(page)
    base = table[table.keep == 1].iloc[0]
    ok = table[(table.keep < 1) & table.settled.fillna(False).astype(bool)]
    head = f"{page.parent.name} ({base.n_gaussians:,.0f} Gaussians, {base.psnr:.2f} dB)"
    if ok.empty:
        return f"{head}: no kept fraction settled within {table.sesoi.iloc[0]:g} dB with {int(base.n)} seeds"
    r = ok.sort_values("keep").iloc[0]
    return (f"{head}: {r.n_gaussians:,.0f} kept ({r.keep:g}) settled within {table.sesoi.iloc[0]:g} dB"
            f" ({r.psnr:.2f} dB)")


def stability_sentence(root: Path) -> str:
    """Per method: the first rung of each ladder where a run broke (k of n), and on how many
    ladders a quality loss is settled at some rung."""
    table = _read(root / "stability" / "ladders.csv")
    if table.empty or "n_broken" not in table:
        return ""
    methods = table[table.role == "method"]
    parts = []
    for v, sub in methods.groupby("variant", sort=False):
        breaks = []
        for lad, rows in sub.groupby("ladder", sort=False):
            at = rows.first_break.iloc[0]
            if not math.isnan(at):
                r = rows[rows.rung == at].iloc[0]
                breaks.append(f"{lad} {r.rung:g} ({r.n_broken}/{r.n_attempted})")
        losing = sub.groupby("ladder", sort=False).first_loss.first().notna().sum()
        parts.append(f"`{v}` breaks first at " + ("; ".join(breaks) if breaks else "no rung")
                     + f" and has a settled quality loss on {losing} of {sub.ladder.nunique()} ladders")
    return ("**Stability** (a break is a crash, divergence or colour collapse, k of n runs; a settled loss: the"
            " rung's colour-aligned PSNR below the base cell's by more than the SESOI, its whole 95% interval): "
            + "; ".join(parts) + " (stability/index.md).")


def answers_markdown(root: Path) -> list[str]:
    """The section's lines ([] when no answer has its table yet)."""
    found = [s for s in (speed_sentence(root), size_sentence(root), stability_sentence(root)) if s]
    if not found:
        return []
    return ["## The brief's three questions, answered", "", *[f"- {s}" for s in found], ""]
