"""``study prune NAME --variants V --scenes S --keep F1,F2,... [--recover N] [--compare V1,V2,...]``.

Prunes every finished run of one variant of a study (its seeds) to each kept fraction by
spatio-temporal significance (``ftgspp/pruning.py``: score, keep, a recovery fine-tune of N
iterations, held-out evaluation), then writes a curve: held-out PSNR (raw and colour-aligned) and
LPIPS against the Gaussians kept, per seed and as means, beside the runs of ``--compare`` variants
trained at those sizes, and the smallest kept fraction whose loss against the unpruned run
(paired by seed) is settled inside the PSNR SESOI (docs/sesoi.md). A pruned run already in
``RUN/pruned/`` is reused (a re-run resumes). Output: ``OUT/<study>_<variant>_<scene>/`` with
``curve.csv``, ``curve.png`` and ``index.md`` naming the command and the code.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from typing import Any

from ftgspp.errors import InputError

PRUNE_METRICS = ("psnr", "psnr_cc", "lpips_alex")
LEVEL = 0.90  # the TOST's interval, as the budget finder's


def add_parser(sub: Any, selection_args: Any, reports_root: Path) -> None:
    """Register ``study prune`` on the ``study`` parser's subparsers."""
    p = sub.add_parser("prune", help="prune a variant's finished runs to kept fractions; a curve against size")
    selection_args(p)
    p.add_argument("--keep", required=True, help="comma-separated kept fractions in (0, 1], e.g. 0.5,0.25,0.1")
    p.add_argument("--recover", type=int, default=300, help="recovery fine-tune iterations (default 300)")
    p.add_argument("--compare", default="", help="comma-separated variants trained at smaller budgets, shown beside")
    p.add_argument("--out", type=Path, default=reports_root / "pruning", help="where the curve goes")


def _fractions(text: str) -> list[float]:
    try:
        keep = sorted({float(x) for x in text.split(",") if x.strip()}, reverse=True)
    except ValueError:
        raise InputError("--keep", f"not a list of numbers: {text!r}") from None
    if not keep or any(not 0 < k <= 1 for k in keep):
        raise InputError("--keep", f"every fraction must be in (0, 1]: {text!r}")
    return keep


def _run_dirs(data: Any) -> list[tuple[int, Path, dict[str, float]]]:
    """(seed, out_dir, metrics) of every finished run of the selection, by seed."""
    out = []
    for r in data.df[data.df.status == "FINISHED"].sort_values("seed").itertuples():
        run = data.store.call(data.store.client.get_run, r.run_id, write=False)
        folder = Path(run.data.tags.get("out_dir", ""))
        if not (folder / "gaussians.pt").is_file():
            raise InputError("study prune", f"run {r.run_id} ({r.variant}, seed {r.seed}) has no gaussians.pt in"
                                            f" {folder} (its outputs are on the machine that trained it)")
        out.append((int(r.seed), folder, {m: float(getattr(r, m, float("nan"))) for m in (*PRUNE_METRICS, "n_gaussians")}))
    return out


def _pruned(run_dir: Path, keep: float, recover: int) -> dict[str, Any]:
    """``prune_run``'s result, read back from its default folder when an earlier call wrote it."""
    from ftgspp.pruning import default_out, prune_run

    done = default_out(run_dir, keep, recover) / "prune.json"
    if done.is_file():
        return json.loads(done.read_text())
    return prune_run(run_dir, keep, recover)


def curve_frame(runs: list[tuple[int, Path, dict[str, float]]], keeps: list[float], recover: int,
                progress: Any = print) -> Any:
    """One row per (seed, kept fraction), plus the unpruned run at fraction 1 (``pruned`` False)."""
    import pandas as pd

    rows = []
    for seed, folder, original in runs:
        rows.append({"seed": seed, "keep": 1.0, "pruned": False, "n_gaussians": original["n_gaussians"],
                     **{m: original[m] for m in PRUNE_METRICS}})
        for keep in keeps:
            res = _pruned(folder, keep, recover)
            m = res["metrics"]
            rows.append({"seed": seed, "keep": keep, "pruned": True, "n_gaussians": m["n_gaussians"],
                         **{k: m.get(k, float("nan")) for k in PRUNE_METRICS}})
            progress(f"  seed {seed}, keep {keep:g}: {int(m['n_gaussians'])} Gaussians, psnr {m['psnr']:.2f} dB")
    return pd.DataFrame(rows)


def settled_loss(frame: Any, sesoi: float) -> Any:
    """Per kept fraction: mean PSNR, its loss against the unpruned run paired by seed, the loss's
    90% interval (scipy's paired t-test) and whether its upper bound is below ``sesoi``."""
    import pandas as pd
    from scipy import stats

    base = frame[~frame.pruned].set_index("seed").psnr
    rows = []
    for keep, sub in frame[frame.pruned].groupby("keep", sort=False):
        s = sub.set_index("seed").psnr.reindex(base.index)
        loss = base - s
        row = {"keep": keep, "n_gaussians": sub.n_gaussians.mean(), "psnr": s.mean(), "loss": loss.mean(),
               "n": int(loss.notna().sum())}
        if row["n"] >= 2 and loss.std() > 0:
            ci = stats.ttest_rel(base, s, nan_policy="omit").confidence_interval(LEVEL)
            row["loss_low"], row["loss_high"] = float(ci.low), float(ci.high)
        else:
            row["loss_low"] = row["loss_high"] = float(loss.mean())
        row["settled"] = bool(row["loss_high"] < sesoi)
        rows.append(row)
    return pd.DataFrame(rows).sort_values("keep", ascending=False)


def cmd_prune(args: argparse.Namespace, selection: Any, argv: list[str]) -> int:
    """Prune, write the curve and its page, print where."""
    from harness.analysis.aggregate import size_tolerance
    from harness.report.prune_page import write_page
    from harness.report.results import collect

    keeps = _fractions(args.keep)
    if len(selection.variants) != 1 or len(selection.scenes) != 1:
        raise InputError("study prune", "give one variant (--variants V) and one scene (--scenes S)")
    data = collect(args.name, selection)
    runs = _run_dirs(data)
    if not runs:
        raise InputError("study prune", f"no finished run of {selection.variants[0]} on {selection.scenes[0]}"
                                        f" in {data.uri} (run the study first)")
    print(f"{args.name}: pruning {len(runs)} runs of {selection.variants[0]} ({selection.scenes[0]}) to"
          f" {', '.join(f'{k:g}' for k in keeps)} with {args.recover} recovery iterations", flush=True)
    frame = curve_frame(runs, keeps, args.recover)
    compare = None
    if args.compare:
        cdf = collect(args.name, dataclasses.replace(selection, variants=args.compare.split(","))).df
        compare = cdf[cdf.status == "FINISHED"]
    sesoi = size_tolerance("psnr")
    page = write_page(args, frame, settled_loss(frame, sesoi), compare, sesoi, argv)
    print(f"report: {page}")
    return 0
