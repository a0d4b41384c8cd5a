"""How long quick runs take: the measured rates behind every estimate of ``make reports``, that
is the planner (``harness.cli.reports_plan``), the README's table and a stale report's refresh
time (``report.currency``).

``QUICK_RUNS_PER_HOUR`` holds, per vector instruction set, the quick runs an hour a study makes
``MEASURED_JOBS`` at a time on an idle 2-core machine, as ``benchmarks/runs_per_hour.py --runs 24``
measured them (BENCHMARKS.md, EPYC-512 znver4, 2026-11-27: 253.3 and 256.9 with AVX-512). The AVX2
rate is that times ``AVX2_RATIO``, AVX2 kernels' quick runs an hour two at a time against AVX-512's
on the same cores as ``benchmarks/cost_table.py`` measured them in one invocation (2026-11-30,
8e46505: 154.7 against 183.0 on a slower day of that host; 178.7 an hour, 0.70x, before the
masked-store fix a8e3b38). Those are studio runs; ``MIX`` is how much longer the studies'
mix of runs (120-frame clips, 20,000-Gaussian ladders, portable mode) takes: a whole
``make reports`` took 2 h 47 min where the benchmark of its day said 2.6 h
(docs/benchmarks-history.md, "`make reports` in one go"). Other ``jobs`` scale the rate by
``study_schema.jobs_speedup``. ``host_isa`` is this machine's widest vector ISA
(``ftgspp.bench.isa``); one without a measured rate (SSE only, not x86) is given the slowest
measured one, and the estimate says so.

    python -c "from harness.spec.throughput import estimate; print(estimate(456).text())"
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

from harness.spec.study_schema import fmt_duration, jobs_speedup

AVX2_RATIO = 0.845  # AVX2 against AVX-512 kernels, quick runs an hour 2 at a time (BENCHMARKS.md, cost table)
QUICK_RUNS_PER_HOUR = {"AVX-512": 255.0, "AVX2": float(round(255.0 * AVX2_RATIO))}  # a study, 2 at a time, idle 2 cores
MEASURED_JOBS = 2  # the rates' runs at a time (make reports and the quick profiles run 2)
MIX = 1.07  # the studies' runs against the benchmark's studio runs: 2 h 47 min measured / 2.6 h estimated


@functools.lru_cache(maxsize=1)
def host_isa() -> str:
    """This machine's widest vector ISA (``AVX-512``, ``AVX2``, ...)."""
    from ftgspp.bench.isa import host_vector_isa

    return host_vector_isa()


@dataclass(frozen=True)
class Estimate:
    """The expected wall time of ``runs`` quick runs, ``jobs`` at a time, on a host of ``isa``."""

    runs: int
    jobs: int
    isa: str
    measured_isa: str  # whose measured rate is used (``isa`` unless none was measured for it)

    @property
    def runs_per_hour(self) -> float:
        return QUICK_RUNS_PER_HOUR[self.measured_isa] * jobs_speedup(self.jobs) / jobs_speedup(MEASURED_JOBS)

    @property
    def seconds(self) -> float:
        return self.runs * MIX / self.runs_per_hour * 3600

    @property
    def hours(self) -> float:
        return self.seconds / 3600

    def rate_text(self) -> str:
        """Where the figure comes from, in one clause."""
        text = f"{QUICK_RUNS_PER_HOUR[self.measured_isa]:.0f} quick runs an hour {MEASURED_JOBS} at a time"
        text += f", measured with {self.measured_isa}"
        if self.isa != self.measured_isa:
            text += f" (none measured with {self.isa}: expect longer)"
        if jobs_speedup(self.jobs) != jobs_speedup(MEASURED_JOBS):
            text += f"; {self.runs_per_hour:.0f} {self.jobs} at a time"
        return text + f"; x{MIX:g} for the studies' mix: harness/spec/throughput.py"

    def duration(self) -> str:
        """``1.9 h`` from an hour on (as the README's table and the planner write it), else ``8 min``."""
        return f"{self.hours:.1f} h" if self.seconds >= 3600 else fmt_duration(self.seconds)

    def text(self) -> str:
        """``~8 min on this machine (255 quick runs an hour 2 at a time, measured with AVX-512, ...)``."""
        return f"~{self.duration()} on this machine ({self.rate_text()})"


def estimate(runs: int, jobs: int = MEASURED_JOBS, isa: str | None = None) -> Estimate:
    """``runs`` quick runs, ``jobs`` at a time, on this machine (or a host of vector ISA ``isa``)."""
    isa = isa or host_isa()
    measured = isa if isa in QUICK_RUNS_PER_HOUR else min(QUICK_RUNS_PER_HOUR, key=QUICK_RUNS_PER_HOUR.get)
    return Estimate(runs, jobs, isa, measured)
