"""The cost table of issue 59: what each method costs, per ISA, from one invocation on one machine.

For each method (as the studies train it) and each kernel target it measures
- a training iteration (ms): ``ftgspp bench train --models ... --backends cpu`` (5,000
  Gaussians, 128x96, the first ``--iterations`` iterations from initialisation, 2 threads; the
  method's ``conf/model`` file only: the bench has no learning-rate option, so STGS at scale 1);
- quick runs an hour one at a time and two at a time, with a run's median training seconds
  and wall seconds: ``benchmarks/runs_per_hour.py`` (a one-variant study of ``--runs`` seeds on
  the studio scene, its own store and scene cache);
and, when both ``host`` and another target were measured, each figure's ratio to ``host``'s
(throughput over throughput: 0.85 means the other target does 85 % of the host's work an hour).

Nothing is asserted; figures from one invocation are comparable with each other. The
measurements run one after another, the targets alternating within each method, so a drift of
the machine's speed spreads over both. It takes about ``methods x targets x (2 studies + 1
bench)`` minutes: with the defaults about 40 on a 2-core EPYC.

    .venv/bin/python benchmarks/cost_table.py                               # ftgs, ftgspp, stg x host, haswell
    .venv/bin/python benchmarks/cost_table.py --methods ftgs --runs 4 --json out.json
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ftgspp.bench.isa import describe, host_isa
from harness.tracking.provenance import git_sha

# The Hydra overrides with which the studies train each method (STGS at its study learning rate).
METHODS = {
    "ftgs": ["model=ftgs"],
    "ftgspp": ["model=ftgspp"],
    "stg": ["model=stg", "lr.scale=3"],
}


def _run_json(cmd: list[str]) -> dict:
    """Run a benchmark command that prints one JSON object last on stdout."""
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        tail = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        raise RuntimeError(f"{' '.join(cmd[1:4])} ... failed: {tail}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def iteration_ms(method: str, target: str, iterations: int, repeats: int) -> float:
    """Median ms of a training iteration (``ftgspp bench train``, ``cpu`` backend)."""
    out = _run_json([sys.executable, "-m", "ftgspp.bench", "train", "--models", method, "--backends", "cpu",
                     "--iterations", str(iterations), "--repeats", str(repeats), "--target", target, "--json"])
    (backend,) = out["backends"].values()  # one model, one backend
    return float(backend["ms_per_iter"])


def runs_per_hour(method: str, target: str, jobs: int, runs: int) -> dict:
    """``benchmarks/runs_per_hour.py``'s summary for one method, target and job count."""
    cmd = [sys.executable, str(ROOT / "benchmarks" / "runs_per_hour.py"), "--runs", str(runs), "--jobs", str(jobs),
           "--target", target, "--json"]
    for override in METHODS[method]:
        cmd += ["--override", override]
    return _run_json(cmd)


def measure(methods: list[str], targets: list[str], runs: int, iterations: int, repeats: int, log=print) -> dict:
    """Every figure of the table, method by method, the targets alternating within a method."""
    table: dict = {}
    for method in methods:
        for target in targets:
            cell = table.setdefault(method, {}).setdefault(target, {})
            log(f"{method} / {target}: bench train")
            cell["iteration_ms"] = iteration_ms(method, target, iterations, repeats)
        for jobs in (1, 2):
            for target in targets:
                log(f"{method} / {target}: {runs} quick runs, {jobs} at a time")
                r = runs_per_hour(method, target, jobs, runs)
                table[method][target][f"jobs{jobs}"] = {
                    "runs_per_hour": r["runs_per_hour"], "steady_runs_per_hour": r["steady_runs_per_hour"],
                    "train_s_median": r["phases_s_median"].get("train_seconds"),
                    "run_wall_s_median": r["run_wall_s_median"], "runs": r["runs"],
                }  # fmt: skip
    return table


def ratios(table: dict, base: str = "host") -> dict:
    """Each non-``base`` target's throughput as a fraction of ``base``'s, per method and figure."""
    out: dict = {}
    for method, cells in table.items():
        if base not in cells:
            continue
        b = cells[base]
        for target, c in cells.items():
            if target == base:
                continue
            r = {"iteration": b["iteration_ms"] / c["iteration_ms"]}
            for jobs in ("jobs1", "jobs2"):
                if jobs in b and jobs in c:
                    r[f"runs_per_hour_{jobs}"] = c[jobs]["runs_per_hour"] / b[jobs]["runs_per_hour"]
                    if b[jobs]["train_s_median"] and c[jobs]["train_s_median"]:
                        r[f"training_{jobs}"] = b[jobs]["train_s_median"] / c[jobs]["train_s_median"]
            out.setdefault(method, {})[target] = r
    return out


def markdown(table: dict, rat: dict) -> str:
    """The table as Markdown: one row per method and target."""
    header = ("| method | kernels | iteration (ms) | quick run: training / wall (s), 2 at a time "
              "| runs an hour, 1 at a time | runs an hour, 2 at a time | vs host (iteration; runs an hour 1 / 2) |")
    lines = [header, "|---|---|---|---|---|---|---|"]
    for method, cells in table.items():
        for target, c in cells.items():
            j1, j2 = c.get("jobs1", {}), c.get("jobs2", {})
            vs = "-"
            if method in rat and target in rat[method]:
                r = rat[method][target]
                vs = (f"{r['iteration']:.2f}x; {r.get('runs_per_hour_jobs1', float('nan')):.2f}x / "
                      f"{r.get('runs_per_hour_jobs2', float('nan')):.2f}x")
            lines.append(
                f"| {method} | {target} | {c['iteration_ms']:.2f} | {j2.get('train_s_median', 0):.1f} / "
                f"{j2.get('run_wall_s_median', 0):.1f} | {j1.get('runs_per_hour', 0):.1f} | "
                f"{j2.get('runs_per_hour', 0):.1f} | {vs} |"
            )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--methods", default="ftgs,ftgspp,stg", help=f"comma-separated, of {', '.join(METHODS)}")
    p.add_argument("--targets", default="host,haswell", help="LLVM CPUs to compile the kernels for")
    p.add_argument("--runs", type=int, default=6, help="quick runs per runs-an-hour study")
    p.add_argument("--iterations", type=int, default=200)
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--json", type=Path, help="also write every figure to this file")
    args = p.parse_args(argv)
    methods = [m for m in args.methods.split(",") if m]
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        print(f"error: --methods: no method {unknown or '(none)'}; known: {', '.join(METHODS)}", file=sys.stderr)
        return 2
    targets = [t for t in args.targets.split(",") if t]
    commit = git_sha()  # of the code measured: taken before the measurements start
    try:
        table = measure(methods, targets, args.runs, args.iterations, args.repeats,
                        log=lambda m: print(m, file=sys.stderr, flush=True))
    except RuntimeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    rat = ratios(table)
    result = {"commit": commit, "machine": describe(host_isa()),
              "cpu_count": os.cpu_count(), "runs": args.runs, "iterations": args.iterations, "table": table,
              "ratios_vs_host": rat}
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
    print(f"commit {result['commit']}, {result['machine']}, {args.runs} quick runs a study, "
          f"bench {args.iterations} iterations")
    print(markdown(table, rat))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
