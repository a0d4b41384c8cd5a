"""Study progress shared by the runs of one invocation, also across worker processes.

Every finished run appends one JSON line to ``<sweep_dir>/progress.jsonl`` under a file
lock and reads back how many runs are done, so each worker can print the study's
progress and an ETA: the seconds a run takes, a blend of the study's own estimate
(``expected``: the plan's figure, worth ``MEASURED_AFTER`` runs) and the measured rate (wall time so
far / runs done), times the runs left. The blend moves smoothly from the plan to the measurement
as runs finish (the first runs of an install also compile the kernels, and a rate from them alone
says hours where minutes are left), and it is never 0 while a run is left.

``expected`` is what ``study run`` prints before it starts: for the quick profile, the quick runs
an hour measured on a host of this one's kind (its vector ISA, ``spec.throughput``) and the
kernels' compile time when their cache is cold (``ftgspp.bench.warmup.COLD_COMPILE_S``); for
another profile, the study file's own figure (``ProfileSpec.estimate``).
"""

from __future__ import annotations

import fcntl
import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

from ftgspp.bench.warmup import COLD_COMPILE_S
from harness.spec import throughput
from harness.spec.study_schema import ProfileSpec, fmt_duration, jobs_speedup, plural

MEASURED_AFTER = 4  # runs done before the ETA trusts the measured rate


@dataclass(frozen=True)
class Progress:
    done: int
    failed: int
    total: int
    elapsed_s: float
    expected_total_s: float = 0.0  # the study's estimate for these runs (0: none)

    @property
    def eta_s(self) -> float:
        """Seconds left: runs left x a blend of the plan's and the measured seconds a run (module docstring)."""
        left = self.total - self.done
        if left <= 0:
            return 0.0
        planned = self.expected_total_s / self.total if self.expected_total_s > 0 and self.total else math.nan
        if self.done == 0:
            return max(self.expected_total_s - self.elapsed_s, planned) if not math.isnan(planned) else math.nan
        measured = self.elapsed_s / self.done
        if math.isnan(planned):
            return measured * left
        per_run = (MEASURED_AFTER * planned + self.done * measured) / (MEASURED_AFTER + self.done)
        return per_run * left

    def line(self) -> str:
        eta = "?" if math.isnan(self.eta_s) else fmt_seconds(self.eta_s)
        return (
            f"study {self.done}/{self.total} runs done, {self.failed} failed, "
            f"elapsed {fmt_seconds(self.elapsed_s)}, ETA {eta}"
        )


def fmt_seconds(seconds: float) -> str:
    """``75 -> '1m15s'``, ``3700 -> '1h01m'``."""
    s = int(round(seconds))
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s // 3600}h{(s % 3600) // 60:02d}m"


def record(path: Path, label: str, status: str, total: int, started_at: float,
           expected_total_s: float = 0.0) -> Progress:
    """Append one finished run and return the study's progress."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a+") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            fh.write(json.dumps({"run": label, "status": status, "time": time.time()}) + "\n")
            fh.flush()
            fh.seek(0)
            rows = [json.loads(line) for line in fh if line.strip()]
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)
    failed = sum(r["status"] != "FINISHED" for r in rows)
    return Progress(len(rows), failed, total, time.time() - started_at, expected_total_s)


def expected(profile: ProfileSpec, n_runs: int, jobs: int, compile_kernels: bool) -> tuple[str, float]:
    """(the plan's expected time, the runs' expected seconds): for the quick profile from the
    quick runs an hour measured on this host's kind (its vector ISA; ``spec.throughput``), plus the
    kernels' compile when their cache is cold (and a word when the machine is busy now); for another
    profile from its own figure."""
    if profile.name != "quick":
        return profile.estimate(n_runs, jobs), n_runs * profile.run_seconds / jobs_speedup(jobs)
    est = throughput.estimate(n_runs, jobs)
    extra = f" + ~{fmt_duration(COLD_COMPILE_S)} to compile the kernels" if compile_kernels else ""
    total = est.seconds + COLD_COMPILE_S * compile_kernels
    load, cores = os.getloadavg()[0], os.cpu_count() or 1
    busy = f"; this machine is busy now (load average {load:.1f} on {cores} cores): expect longer" * (load >= cores)
    return (f"~{fmt_duration(total)} on an idle 2-core {est.isa} machine, this one's kind ({plural(n_runs, 'run')}"
            f"{extra}; {est.rate_text()}){busy}"), est.seconds
