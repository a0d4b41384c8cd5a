"""The cost table's plumbing (the script itself runs real benchmarks): the order it measures
in, its ratios against the host's kernels and its Markdown, and its one-line errors."""

from __future__ import annotations

import pytest
from bench_scripts import load_script


def load():
    return load_script("cost_table")


def fake_study(train_s: float, jobs: int) -> dict:
    """``runs_per_hour.py --json``'s fields the table reads: a study of 6 runs taking 6 x train_s / jobs."""
    return {"runs_per_hour": 3600.0 * jobs / train_s, "steady_runs_per_hour": None, "run_wall_s_median": train_s + 2,
            "phases_s_median": {"train_seconds": train_s}, "runs": 6}


def test_it_measures_every_cell_alternating_targets_and_divides_by_the_hosts(monkeypatch) -> None:
    t = load()
    calls = []
    speed = {"host": 1.0, "haswell": 1.25}  # AVX2 25 % slower at everything

    def iteration_ms(method, target, iterations, repeats):
        calls.append(("bench", method, target))
        return 4.0 * speed[target] * (3.0 if method == "stg" else 1.0)

    def runs_per_hour(method, target, jobs, runs):
        calls.append(("runs", method, target, jobs))
        return fake_study(10.0 * speed[target], jobs)

    monkeypatch.setattr(t, "iteration_ms", iteration_ms)
    monkeypatch.setattr(t, "runs_per_hour", runs_per_hour)
    table = t.measure(["ftgs", "stg"], ["host", "haswell"], runs=6, iterations=10, repeats=1, log=lambda m: None)
    assert calls[:6] == [("bench", "ftgs", "host"), ("bench", "ftgs", "haswell"), ("runs", "ftgs", "host", 1),
                         ("runs", "ftgs", "haswell", 1), ("runs", "ftgs", "host", 2), ("runs", "ftgs", "haswell", 2)]
    assert len(calls) == 12 and table["stg"]["haswell"]["iteration_ms"] == pytest.approx(15.0)
    rat = t.ratios(table)
    assert set(rat) == {"ftgs", "stg"} and set(rat["ftgs"]) == {"haswell"}  # no host-vs-host row
    for figure in ("iteration", "runs_per_hour_jobs1", "runs_per_hour_jobs2", "training_jobs1", "training_jobs2"):
        assert rat["ftgs"]["haswell"][figure] == pytest.approx(0.8), figure
    md = t.markdown(table, rat).splitlines()
    assert len(md) == 2 + 4 and md[0].count("|") == 8
    row = next(line for line in md if line.startswith("| stg | haswell |"))
    assert "| 15.00 |" in row and "0.80x; 0.80x / 0.80x" in row


def test_an_unknown_method_is_one_line_and_exit_status_2(capsys) -> None:
    t = load()
    assert t.main(["--methods", "ftgs,nerf"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nerf" in err[0] and "ftgs" in err[0]
