"""Quick runs per hour, end to end, as a study makes them (issue 23: the figure that buys answers).

Runs a one-variant study of ``--runs`` seeds with ``study run`` in a fresh folder (its own
SQLite store, scene cache and outputs; ``--jobs`` at a time, 2 by default as the quick
profiles do) and reports runs per hour, plus where a run's wall time goes: training (the
trainer's ``train_seconds``), and everything else in the run (start-up, imports, scene
loading, initialisation, evaluation, LPIPS, diagnostics, MLflow logging), and the study's
fixed cost before its first run (scene synthesis, kernel warm-up), and the steady rate once
every worker has finished its first run (what a long study approaches). Nothing is asserted:
compare figures from one run of this script.

    .venv/bin/python benchmarks/runs_per_hour.py                    # 6 quick runs on studio
    .venv/bin/python benchmarks/runs_per_hour.py --runs 8 --preset transient --json
    .venv/bin/python benchmarks/runs_per_hour.py --target haswell   # as on an AVX2-only host

``--target CPU`` makes every process of the study compile its Numba kernels for that LLVM CPU
(its default features, in a kernel cache of its own that a warm-up fills before the clock
starts) and caps torch and oneDNN at its vector ISA, as ``ftgspp bench --target`` does, so an
AVX-512 host measures what an AVX2 host's instruction set gives (not its microarchitecture).

``--gc-log`` also times Python's garbage collector in every process of the study
(``benchmarks/gclog/sitecustomize.py``) and reports, per process, the generation-2 collections
and their seconds (the two workers are the processes with the most).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from harness.spec.metrics import phases  # noqa: E402

STUDY = """name: rph
question: How many quick runs an hour does this machine make?
baseline: baseline
variants:
  baseline: []
base_seed: 0
metrics: [psnr]
table: {{layout: variants_x_scenes, metrics: [psnr]}}
plots: []
profiles:
  quick:
    jobs: {jobs}
    seeds: {runs}
    overrides: [profile={profile}{extra}]
    scenes:
      - {{name: {preset}, synth: {{preset: {preset}, seed: 0}}}}
    command: study run rph --profile quick
  paper:
    seeds: 1
    overrides: [profile=paper]
    scenes:
      - {{name: {preset}, synth: {{preset: {preset}, seed: 0}}}}
"""


PHASES = phases()  # the trainer's phase timings in the order they run (the metric registry)


def summarise(wall_s: float, runs: list[dict], study_start: float, jobs: int = 2) -> dict:
    """Runs per hour over the whole study and the median split of a run's wall time.

    ``runs``: one dict per finished run with ``start``/``end`` (epoch seconds, MLflow's run
    times) and the trainer's phase timings (``PHASES``); ``study_start``: when ``study run``
    was started. ``rest_s`` is the run's wall time the phases do not cover (process start-up,
    imports, scene loading, logging).

    ``steady_runs_per_hour``: the runs that ended after the ``jobs``-th run to end, over the
    time from that end to the last (None with fewer than ``jobs + 1`` runs). The first
    ``jobs`` ends are normally each worker's first run (a worker that finished two runs before
    another finished its first would leave that slow first run in), so the figure leaves out
    what a study pays once (start-up, scene synthesis, the workers' first runs): it is what a
    long study approaches; the whole-study rate is what a study of this many runs gets.
    """
    walls = [r["end"] - r["start"] for r in runs]
    phases = {p: statistics.median(r.get(p, 0.0) for r in runs) for p in PHASES}
    rest = [w - sum(r.get(p, 0.0) for p in PHASES) for w, r in zip(walls, runs)]
    ends = sorted(r["end"] for r in runs)
    steady = None
    if len(ends) > jobs and ends[-1] > ends[jobs - 1]:
        steady = 3600.0 * (len(ends) - jobs) / (ends[-1] - ends[jobs - 1])
    return {
        "runs": len(runs), "wall_s": wall_s, "runs_per_hour": 3600.0 * len(runs) / wall_s,
        "steady_runs_per_hour": steady,
        "run_wall_s_median": statistics.median(walls), "phases_s_median": phases,
        "rest_s_median": statistics.median(rest), "before_first_run_s": min(r["start"] for r in runs) - study_start,
    }  # fmt: skip


def summarise_gc(log: Path) -> list[dict]:
    """Per process of a ``--gc-log`` study, the generation-2 collections and their seconds (and
    generation 1's), most seconds first, from the lines ``pid generation seconds collected``."""
    per: dict[int, dict] = {}
    if log.exists():
        for line in log.read_text().splitlines():
            fields = line.split()
            if len(fields) != 4:  # a line cut short by a killed process
                continue
            pid, gen, seconds, _ = fields
            p = per.setdefault(int(pid), {"pid": int(pid), "gen2": 0, "gen2_s": 0.0, "gen1": 0, "gen1_s": 0.0})
            key = "gen2" if gen == "2" else "gen1"
            p[key] += 1
            p[key + "_s"] += float(seconds)
    return sorted(per.values(), key=lambda p: -p["gen2_s"])


def target_environment(target: str, cache: Path) -> dict[str, str]:
    """Environment of a study whose processes compile their kernels for ``target`` into ``cache``
    and run torch's kernels for its ISA (``ftgspp.bench.isa``)."""
    from ftgspp.bench.isa import target_environment as isa_target_environment

    return {**isa_target_environment(target), "NUMBA_CACHE_DIR": str(cache)}


def study_yaml(jobs: int, runs: int, profile: str, preset: str, overrides: list[str]) -> str:
    """The one-variant study the benchmark runs, every run with ``profile`` and ``overrides``."""
    return STUDY.format(jobs=jobs, runs=runs, profile=profile, preset=preset, extra="".join(f", {o}" for o in overrides))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=int, default=6)
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--preset", default="studio")
    p.add_argument("--profile", default="quick", help="the trainer profile of each run (quick or smoke)")
    p.add_argument("--target", default="host", help="LLVM CPU to compile the kernels for (default: host)")
    p.add_argument("--gc-log", action="store_true", help="time the garbage collector in every process")
    p.add_argument("--override", action="append", default=[],
                   help="a Hydra override for every run, repeatable (STGS as the studies train it:"
                        " --override model=stg --override lr.scale=3)")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    if args.target != "host":
        from ftgspp.bench.isa import check_target
        from ftgspp.errors import InputError

        try:
            check_target(args.target)
        except InputError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    with tempfile.TemporaryDirectory(prefix="ftgspp-rph-") as tmp:
        work = Path(tmp)
        studies = work / "studies"
        studies.mkdir()
        (studies / "rph.yaml").write_text(study_yaml(args.jobs, args.runs, args.profile, args.preset, args.override))
        # this machine's own kernels unless --target: no inherited CPU or dispatch choices
        from ftgspp.bench.isa import without_isa_choices

        env = without_isa_choices({k: v for k, v in os.environ.items() if k != "MLFLOW_TRACKING_URI"})
        env.update(FTGSPP_STUDIES=str(studies), PYTHONPATH=str(ROOT))
        gc_log = work / "gc.log"
        if args.gc_log:
            env.update(PYTHONPATH=os.pathsep.join([str(ROOT / "benchmarks" / "gclog"), str(ROOT)]),
                       FTGSPP_GC_LOG=str(gc_log))
        if args.target != "host":
            env.update(target_environment(args.target, work / "numba-cache"))
            warm = [sys.executable, "-m", "ftgspp.bench", "train", "--backends", "cpu", "--iterations", "2",
                    "--repeats", "1", "--json"]  # the kernels compiled for the target before the clock starts
            warm_env = {k: v for k, v in env.items() if k != "FTGSPP_GC_LOG"}  # not part of the study
            proc = subprocess.run(warm, cwd=work, env=warm_env, capture_output=True, text=True)
            if proc.returncode != 0:
                print(f"error: compiling the kernels for {args.target} failed: "
                      + (proc.stderr.strip().splitlines() or ["no output"])[-1], file=sys.stderr)
                return 1
        start = time.time()
        proc = subprocess.run([sys.executable, "-m", "harness.cli.study", "run", "rph", "--profile", "quick"],
                              cwd=work, env=env, capture_output=True, text=True)
        wall = time.time() - start
        if proc.returncode != 0:
            print(proc.stdout[-2000:] + proc.stderr[-2000:], file=sys.stderr)
            return 1
        from harness.tracking.records import load_runs, open_store

        store = open_store(f"sqlite:///{work / 'mlflow.db'}")
        runs = []
        for rec in load_runs(store, "ftgspp/rph", "rph"):
            if rec.status == "FINISHED":
                info = store.client.get_run(rec.run_id).info
                runs.append({"start": info.start_time / 1000.0, "end": info.end_time / 1000.0,
                             **{p: rec.metrics[p] for p in PHASES if p in rec.metrics}})
        collections = summarise_gc(gc_log) if args.gc_log else None
    result = {**summarise(wall, runs, start, args.jobs), "jobs": args.jobs, "preset": args.preset, "profile": args.profile,
              "overrides": args.override, "target": args.target,
              "cpu_count": os.cpu_count(), "load_average_after": os.getloadavg()[0]}
    if collections is not None:
        result["gc_per_process"] = collections
    if args.json:
        print(json.dumps(result))
    else:
        print(f"{result['runs']} {args.profile} runs on {args.preset}, {args.jobs} at a time, kernels for "
              f"{args.target}: {wall / 60:.1f} min,"
              f" {result['runs_per_hour']:.0f} runs per hour"
              + (f" ({result['steady_runs_per_hour']:.0f} once every worker has finished a run)"
                 if result["steady_runs_per_hour"] else ""))
        ph = result["phases_s_median"]
        print(f"per run (medians, s): wall {result['run_wall_s_median']:.1f}; " + ", ".join(
            f"{p.removesuffix('_seconds')} {ph[p]:.1f}" for p in PHASES)
            + f", the rest (start-up, imports, loading, logging) {result['rest_s_median']:.1f}")
        print(f"before the first run: {result['before_first_run_s']:.1f} s (scene synthesis, kernel warm-up)")
        for c in result.get("gc_per_process", [])[:3]:
            print(f"process {c['pid']}: {c['gen2']} full garbage collections, {c['gen2_s']:.2f} s"
                  f" ({c['gen1']} of generation 1, {c['gen1_s']:.2f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
