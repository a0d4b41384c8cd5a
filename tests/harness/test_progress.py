"""Progress a person can trust: the study's own estimate until runs have finished, then the rate."""

from __future__ import annotations

import math

from harness.run.progress import MEASURED_AFTER, Progress
from harness.spec.study_schema import ProfileSpec, fmt_duration


def test_eta_moves_from_the_estimate_to_the_measured_rate_smoothly_and_never_says_0_while_runs_are_left() -> None:
    # 25 runs expected to take 780 s (31.2 s a run); the first run took 300 s: it compiled the kernels
    planned = 780.0 / 25
    first = Progress(done=1, failed=0, total=25, elapsed_s=300.0, expected_total_s=780.0)
    blend = (MEASURED_AFTER * planned + 300.0) / (MEASURED_AFTER + 1)
    assert first.eta_s == blend * 24 and first.eta_s < 300.0 * 24  # not 300 x 24 = 2 h
    # the ETA of a study whose runs go as planned stays put as they finish (the issue saw
    # 5m43s -> 2m33s -> 34m39s); a study slower than planned sees it grow toward the measured rate
    steady = [Progress(done=k, failed=0, total=25, elapsed_s=k * planned, expected_total_s=780.0).eta_s + k * planned
              for k in range(1, 25)]
    assert max(steady) - min(steady) < 1e-6
    slow = [Progress(done=k, failed=0, total=25, elapsed_s=k * 2 * planned, expected_total_s=780.0) for k in (2, 8, 20)]
    per_run = [p.eta_s / (25 - p.done) for p in slow]
    assert per_run == sorted(per_run) and planned < per_run[0] and per_run[-1] < 2 * planned
    unknown = Progress(done=0, failed=0, total=3, elapsed_s=10.0)
    assert math.isnan(unknown.eta_s) and "ETA ?" in unknown.line()
    late = Progress(done=1, failed=0, total=25, elapsed_s=900.0, expected_total_s=780.0)
    assert late.eta_s > 0 and "ETA 0s" not in late.line()  # past the plan with runs left: never 0
    nothing_yet = Progress(done=0, failed=0, total=25, elapsed_s=900.0, expected_total_s=780.0)
    assert nothing_yet.eta_s == planned  # at least one run's worth
    assert Progress(done=25, failed=0, total=25, elapsed_s=900.0, expected_total_s=780.0).eta_s == 0.0


def test_a_profile_states_its_expected_runtime_and_machine() -> None:
    prof = ProfileSpec("quick", 5, (), (), {}, run_seconds=40.0, machine="an idle 2-core machine", jobs=2)
    assert prof.estimate(25, 2) == "~12 min (25 runs x ~40 s, 2 at a time) on an idle 2-core machine"
    assert prof.estimate(1, 1) == "~40 s (1 run x ~40 s) on an idle 2-core machine"
    assert fmt_duration(3700) == "1 h 02 min"


def test_a_cold_kernel_cache_is_announced_and_compiled_once(monkeypatch) -> None:
    import sys

    import ftgspp.bench.warmup
    from harness.run import runner

    lines: list[str] = []
    monkeypatch.setattr(ftgspp.bench.warmup, "kernels_cached", lambda: True)
    runner.warm_kernels(lines.append)
    assert lines == []  # a warm cache: nothing to say, nothing run
    monkeypatch.setattr(ftgspp.bench.warmup, "kernels_cached", lambda: False)
    monkeypatch.setattr(runner, "WARMUP", (sys.executable, "-c", "print(1.0)"))
    runner.warm_kernels(lines.append)
    assert lines[0].startswith("compiling the CPU kernels (once per install") and "kernels compiled in" in lines[1]
