"""Why two runs side by side give less than twice one run's throughput: a contention probe.

Two quick runs at a time made 1.36x (znver4) and 1.58x (znver5) the runs an hour of one run at a
time (BENCHMARKS.md), not 2x. This script separates the causes it can from inside the machine, by
timing the same single-threaded work alone and then as two processes at once:

- ``alu``: a pure-Python integer loop (no memory traffic beyond the core's own caches). Two at
  once as fast as one alone means two whole cores; about 1.6x slower each means the two vCPUs
  share one physical core (hyperthreads the guest cannot see), or the host takes time from them;
- ``train``: FreeTimeGS training iterations on the ``cpu`` backend (``ftgspp bench train``,
  5,000 Gaussians, 128x96) with torch, Numba and OpenMP held to one thread. A slowdown beyond the
  ``alu`` probe's is what the training shares besides the cores: the L3 cache and memory;
- ``train2``: the same with each process's default threads (one per core), as a study's runs
  train today: two at once put two threads on each core.

"Pair vs one" is the pair's throughput against one process alone of the same probe; a study's
two-at-a-time gain is ``train2``'s pair against ``train2`` alone.

Each probe runs ``--rounds`` times alone and as a pair, alternating; the table gives medians,
each process's slowdown in the pair and the pair's throughput against one alone (2 / slowdown).

    .venv/bin/python benchmarks/concurrency.py [--rounds 3] [--iterations 150] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

ALU = "import time\nt = time.perf_counter()\nx = 0\nfor i in range({n}):\n    x = (x * 31 + i) & 0xFFFF\nprint(time.perf_counter() - t)"
ONE_THREAD = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}


def command(probe: str, size: int) -> list[str]:
    """The probe's command line (``train2``: ``train``'s, with other threads)."""
    if probe == "alu":
        return [sys.executable, "-c", ALU.format(n=size)]
    return [sys.executable, "-m", "ftgspp.bench", "train", "--models", "ftgs", "--backends", "cpu",
            "--iterations", str(size), "--repeats", "1", "--json"]


def seconds(probe: str, out: str) -> float:
    """The probe's time from its output: the loop's seconds, or the training's ms per iteration."""
    last = out.strip().splitlines()[-1]
    if probe == "alu":
        return float(last)
    (backend,) = json.loads(last)["backends"].values()  # one model, one backend
    return float(backend["ms_per_iter"])


def run(probe: str, size: int, at_once: int) -> list[float]:
    env = dict(os.environ, **ONE_THREAD) if probe != "train2" else dict(os.environ)
    procs = [subprocess.Popen(command(probe, size), env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                              text=True) for _ in range(at_once)]
    outs = [p.communicate()[0] for p in procs]
    if any(p.returncode for p in procs):
        raise RuntimeError(f"a {probe} probe failed")
    return [seconds(probe, o) for o in outs]


def measure(probe: str, size: int, rounds: int) -> dict:
    alone, pair = [], []
    for r in range(rounds):
        for n in (1, 2) if r % 2 == 0 else (2, 1):
            (alone if n == 1 else pair).extend(run(probe, size, n))
    a, p = statistics.median(alone), statistics.median(pair)
    return {"alone": a, "in_pair": p, "slowdown": p / a, "pair_throughput": 2 * a / p, "all_alone": alone,
            "all_pair": pair}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--iterations", type=int, default=150, help="training iterations a train probe times")
    parser.add_argument("--loop", type=int, default=20_000_000, help="iterations of the alu probe's loop")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    t0 = time.time()
    result = {"alu": measure("alu", args.loop, args.rounds), "train": measure("train", args.iterations, args.rounds),
              "train2": measure("train2", args.iterations, args.rounds), "seconds": time.time() - t0}
    if args.json:
        print(json.dumps(result, indent=1))
        return 0
    print(f"{args.rounds} rounds alternating alone / two at once (medians); alu and train: one thread a process")
    print(f"{'probe':8}{'alone':>12}{'in a pair':>12}{'slowdown':>10}{'pair vs one':>13}")
    for probe, unit in (("alu", "s"), ("train", "ms/it"), ("train2", "ms/it")):
        r = result[probe]
        print(f"{probe:8}{r['alone']:>9.3f} {unit:<2}{r['in_pair']:>9.3f} {unit:<2}{r['slowdown']:>9.2f}x"
              f"{r['pair_throughput']:>12.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
