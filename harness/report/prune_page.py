"""The page of ``study prune``: ``curve.csv``, ``settled.csv``, ``curve.png`` and ``index.md`` under
``OUT/<study>_<variant>_<scene>/`` (held-out PSNR, colour-aligned PSNR and LPIPS against the
Gaussians kept, beside runs trained at smaller budgets, and the smallest settled fraction)."""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path
from typing import Any

import pandas as pd

from harness.report.plots import save_figure

PANELS = (("psnr", "held-out PSNR (dB)"), ("psnr_cc", "colour-aligned PSNR (dB)"), ("lpips_alex", "LPIPS (AlexNet)"))


def _plot(frame: pd.DataFrame, compare: pd.DataFrame | None, title: str, path: Path) -> Path:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(PANELS), figsize=(13.5, 3.8))
    for ax, (metric, name) in zip(axes, PANELS):
        for seed, sub in frame.groupby("seed"):
            sub = sub.sort_values("n_gaussians")
            ax.plot(sub.n_gaussians, sub[metric], "o-", color="C0", alpha=0.35, ms=3,
                    label="pruned + recovered (a seed)" if seed == frame.seed.min() else None)
        mean = frame.groupby("keep").agg(n=("n_gaussians", "mean"), v=(metric, "mean")).sort_values("n")
        ax.plot(mean.n, mean.v, "o-", color="C0", lw=2, label="mean over seeds")
        if compare is not None and metric in compare and len(compare):
            c = compare.groupby("variant").agg(n=("n_gaussians", "mean"), v=(metric, "mean")).sort_values("n")
            ax.plot(c.n, c.v, "s--", color="C3", label="trained at that budget (mean)")
        ax.set_xscale("log")
        ax.set_xlabel("Gaussians")
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    return save_figure(fig, path)


def write_page(args: argparse.Namespace, frame: pd.DataFrame, settled: pd.DataFrame, compare: pd.DataFrame | None,
               sesoi: float, argv: list[str]) -> Path:
    """Write curve.csv, settled.csv, curve.png and index.md; returns the page's path."""
    from harness.tracking.provenance import git_sha, trainer_fingerprint

    variant, scene = args.variants[0], args.scenes[0]
    out = Path(args.out) / f"{args.name}_{variant}_{scene}"
    out.mkdir(parents=True, exist_ok=True)
    frame.to_csv(out / "curve.csv", index=False)
    base = frame[~frame.pruned]
    unpruned = pd.DataFrame([{"keep": 1.0, "n_gaussians": base.n_gaussians.mean(), "psnr": base.psnr.mean(),
                              "loss": 0.0, "n": len(base)}])
    pd.concat([unpruned, settled], ignore_index=True).assign(sesoi=sesoi).to_csv(out / "settled.csv", index=False)
    title = f"{args.name}: {variant} on {scene}, pruned by significance, {args.recover} recovery iterations"
    _plot(frame, compare, title, out / "curve.png")
    lines = [f"# Pruning `{variant}` on `{scene}` ({args.name})", "",
             f"Every finished run of `{variant}` ({len(base)} seeds, {base.n_gaussians.mean():,.0f} Gaussians) pruned"
             f" to the kept fractions by spatio-temporal significance, then {args.recover} recovery iterations"
             " (docs/pruning.md). Loss = unpruned − pruned held-out PSNR, paired by seed, with its 90% interval"
             f" (scipy's paired t-test); settled when the interval's upper end is below the SESOI ({sesoi:g} dB,"
             " docs/sesoi.md).", "",
             "| kept | Gaussians | PSNR (dB) | loss (dB) [90%] | seeds | settled within the SESOI |",
             "|---:|---:|---:|---:|---:|---|",
             f"| 1 (unpruned) | {base.n_gaussians.mean():,.0f} | {base.psnr.mean():.2f} ± {base.psnr.std():.2f} | — |"
             f" {len(base)} | — |"]
    for r in settled.itertuples():
        lines.append(f"| {r.keep:g} | {r.n_gaussians:,.0f} | {r.psnr:.2f} | {r.loss:+.2f} [{r.loss_low:+.2f},"
                     f" {r.loss_high:+.2f}] | {r.n} | {'yes' if r.settled else 'no'} |")
    ok = settled[settled.settled]
    lines.append("")
    if len(ok):
        r = ok.sort_values("keep").iloc[0]
        lines.append(f"**Smallest settled:** keep {r.keep:g}, {r.n_gaussians:,.0f} Gaussians, within {sesoi:g} dB of"
                     f" the unpruned model (loss {r.loss:+.2f}, upper 90% bound {r.loss_high:+.2f}).")
    else:
        lines.append(f"**No kept fraction is settled within {sesoi:g} dB** of the unpruned model with these seeds.")
    if compare is not None and len(compare):
        c = compare.groupby("variant").agg(n=("n_gaussians", "mean"), psnr=("psnr", "mean"), runs=("psnr", "size"))
        lines += ["", "Trained at that budget from the start (the study's runs, same scene):", "",
                  "| variant | Gaussians | PSNR (dB) | runs |", "|---|---:|---:|---:|"]
        lines += [f"| `{v}` | {r.n:,.0f} | {r.psnr:.2f} | {int(r.runs)} |" for v, r in c.sort_values("n").iterrows()]
    command = "study " + " ".join(shlex.quote(a) for a in argv)
    lines += ["", "![curve](curve.png)", "",
              f"Made by `{command}` at commit `{git_sha()}`; trainer `{trainer_fingerprint()}` (pruning and"
              " recovery run in this checkout's code)."]
    (out / "index.md").write_text("\n".join(lines) + "\n")
    return out / "index.md"
