"""The issue-23 table: the ``cpu`` backend's figures per vector ISA, before and after, in one run.

For each code version (``--before REV``, default the commit before the ISA work began, and
this tree) and each CPU target (``--targets``, default ``host,haswell``: this machine's own
kernels, and what an AVX2-only host gets), runs ``ftgspp bench render`` and ``ftgspp bench
train`` in child processes with that version on ``PYTHONPATH``, a fresh Numba cache of their
own (compiled by a warm-up child first, so the timed children load cached kernels as a
user's processes do) and, for a named target, the environment of a host of that CPU
(``NUMBA_CPU_NAME`` with its default features; torch and oneDNN capped at its ISA). Rounds
alternate the versions, so drift in the machine's load touches both alike. Nothing is
asserted: it prints the table (Markdown) and, with ``--json``, every child's result.

    .venv/bin/python benchmarks/isa_table.py                       # before fa5db78 vs this tree
    .venv/bin/python benchmarks/isa_table.py --before HEAD~3 --rounds 2 --json out.json
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from io import BytesIO
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ftgspp.bench.isa import check_target, target_environment, without_isa_choices  # noqa: E402
from ftgspp.errors import InputError  # noqa: E402

BEFORE = "fa5db78"  # the last commit before `ftgspp bench` named the ISA (issue 23's starting point)
RENDER = ["render", "--repeats", "50", "--yardstick-repeats", "1", "--no-compile-times", "--json"]
TRAIN = ["train", "--backends", "cpu", "--iterations", "200", "--repeats", "2", "--json"]
WARMUP = (["render", "--repeats", "1", "--yardstick-repeats", "0", "--no-compile-times", "--json"],
          ["train", "--backends", "cpu", "--iterations", "2", "--repeats", "1", "--json"])

# (row label, function of (render result, train result) -> milliseconds)
FIGURES = (
    ("`ftgspp bench render`, cpu fwd+bwd (ms)", lambda r, t: r["backends"]["cpu"]["fwd_bwd_ms"]),
    ("`ftgspp bench render`, cpu fwd (ms)", lambda r, t: r["backends"]["cpu"]["fwd_ms"]),
    ("dense yardstick fwd+bwd (ms)", lambda r, t: (r.get("yardstick") or {}).get("fwd_bwd_ms")),
    ("`ftgspp bench train`, cpu ms per iteration", lambda r, t: t["backends"]["cpu"]["ms_per_iter"]),
    ("fused time-eval + SH + projection, fwd+bwd (ms)", lambda r, t: r["stages"]["prepare"]["fused_ms"]),
    ("Numba SSIM loss, fwd+bwd (ms)", lambda r, t: r["stages"]["ssim_loss"]["numba_ms"]),
)


def export(rev: str, dest: Path) -> Path:
    """The tree of commit ``rev`` unpacked into ``dest`` (``git archive``: no worktree left behind)."""
    data = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", rev], check=True,
                          capture_output=True).stdout
    with tarfile.open(fileobj=BytesIO(data)) as tar:
        tar.extractall(dest, filter="data")
    return dest


def child_env(tree: Path, target: str, cache: Path) -> dict[str, str]:
    """The environment of one child: ``tree``'s package, its own kernel cache, ``target``'s ISA."""
    env = without_isa_choices({k: v for k, v in os.environ.items() if k != "FTGSPP_DETERMINISM"})
    env.update(PYTHONPATH=str(tree), NUMBA_CACHE_DIR=str(cache), FTGSPP_BENCH_CHILD="1")
    if target != "host":
        env.update(target_environment(target))
    return env


def bench(tree: Path, env: dict[str, str], argv: list[str]) -> dict:
    """One ``python -m ftgspp.bench <argv>`` child in ``tree``; its JSON result."""
    proc = subprocess.run([sys.executable, "-m", "ftgspp.bench", *argv], cwd=tree, env=env,
                          capture_output=True, text=True, timeout=3600)
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        raise SystemExit(f"bench {' '.join(argv[:1])} failed in {tree} (exit {proc.returncode}): {last}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def table(results: dict, versions: list[str], targets: list[str]) -> str:
    """Markdown: one row per figure, one column per (target, version), medians over rounds."""
    cols = [(t, v) for t in targets for v in versions]
    head = ["figure (5,000 Gaussians, 128×96)"] + [f"{t} ({results['isa'].get(t, '?')}) {v}" for t, v in cols]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for label, get in FIGURES:
        cells = []
        for t, v in cols:
            values = [x for x in (get(r, tr) for r, tr in results["runs"][t][v]) if x is not None]
            cells.append(f"{statistics.median(values):,.2f}" if values else "–")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", default=BEFORE, help=f"commit to compare against (default {BEFORE})")
    ap.add_argument("--targets", default="host,haswell", help="comma-separated LLVM CPUs (host: this machine)")
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--json", type=Path, help="also write every child's result here")
    args = ap.parse_args(argv)
    targets = [t.strip() for t in args.targets.split(",") if t.strip()]
    try:
        for t in targets:
            if t != "host":
                check_target(t)  # known, and executable on this host
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True, check=True).stdout.strip()
    dirty = bool(subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain"],
                                capture_output=True, text=True).stdout.strip())
    after = head + ("+changes" if dirty else "")
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="ftgspp-isa-table-") as tmp:
        tmp = Path(tmp)
        trees = {args.before: export(args.before, tmp / "before"), after: ROOT}
        results = {"before": args.before, "after": after, "isa": {}, "runs": {t: {v: [] for v in trees} for t in targets},
                   "host": os.uname().nodename, "load_average": []}
        caches = {(t, v): tmp / f"cache-{t}-{i}" for t in targets for i, v in enumerate(trees)}
        for (t, v), cache in caches.items():  # compile every version's kernels for every target first
            print(f"compiling {v} for {t} ...", file=sys.stderr, flush=True)
            for warm in WARMUP:
                bench(trees[v], child_env(trees[v], t, cache), warm)
        for rnd in range(args.rounds):
            order = list(trees) if rnd % 2 == 0 else list(reversed(trees))
            for t in targets:
                for v in order:
                    env = child_env(trees[v], t, caches[(t, v)])
                    print(f"round {rnd + 1}/{args.rounds}: {v} on {t} ...", file=sys.stderr, flush=True)
                    r, tr = bench(trees[v], env, RENDER), bench(trees[v], env, TRAIN)
                    results["runs"][t][v].append((r, tr))
                    results["load_average"].append(os.getloadavg()[0])
                    if "isa" in tr:  # versions before the ISA work do not report it
                        results["isa"][t] = f"{tr['isa']['numba_isa']}, torch {tr['isa']['torch_kernels']}"
                    if args.json:  # every finished pair kept, should a later child fail
                        args.json.write_text(json.dumps(results, indent=1))
    results["wall_s"] = time.perf_counter() - start
    print(table(results, list(results["runs"][targets[0]]), targets))
    print(f"\n{args.rounds} round(s) in {results['wall_s'] / 60:.1f} min; 1-min load after each pair: "
          + ", ".join(f"{x:.1f}" for x in results["load_average"]))
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
