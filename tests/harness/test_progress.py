"""Progress a person can trust: the study's own estimate until runs have finished, then the rate."""

from __future__ import annotations

import math

from harness.run.progress import MEASURED_AFTER, Progress
from harness.spec.study_schema import ProfileSpec, fmt_duration


def test_eta_comes_from_the_estimate_until_enough_runs_finished() -> None:
    # 25 runs expected to take 780 s; the first run took 300 s because it compiled the kernels
    first = Progress(done=1, failed=0, total=25, elapsed_s=300.0, expected_total_s=780.0)
    assert first.eta_s == 480.0  # not 300 x 24 = 2 h
    later = Progress(done=MEASURED_AFTER, failed=0, total=25, elapsed_s=400.0, expected_total_s=780.0)
    assert later.eta_s == 400.0 / MEASURED_AFTER * (25 - MEASURED_AFTER)
    unknown = Progress(done=0, failed=0, total=3, elapsed_s=10.0)
    assert math.isnan(unknown.eta_s) and "ETA ?" in unknown.line()
    late = Progress(done=1, failed=0, total=25, elapsed_s=900.0, expected_total_s=780.0)
    assert late.eta_s == 0.0  # past the estimate: never negative


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
