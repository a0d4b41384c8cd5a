"""benchmarks/concurrency.py: the same single-threaded work alone and two at once, alternating; each
process's slowdown in the pair and the pair's throughput against one alone."""

from __future__ import annotations

import json

import pytest
from bench_scripts import load_script

cc = load_script("concurrency")


def test_a_probe_alternates_alone_and_paired_and_the_pair_counts_two_processes(monkeypatch) -> None:
    order = []

    def fake(probe, size, at_once):
        order.append(at_once)
        return [1.0] if at_once == 1 else [1.25, 1.35]

    monkeypatch.setattr(cc, "run", fake)
    r = cc.measure("alu", 10, 3)
    assert order == [1, 2, 2, 1, 1, 2]
    assert r["alone"] == 1.0 and r["in_pair"] == pytest.approx(1.3)
    assert r["slowdown"] == pytest.approx(1.3) and r["pair_throughput"] == pytest.approx(2 / 1.3)


def test_each_probe_is_read_from_its_own_output() -> None:
    assert cc.seconds("alu", "noise\n0.75\n") == 0.75
    line = json.dumps({"backends": {"cpu": {"ms_per_iter": 6.5}}})  # one model: keyed by backend
    assert cc.seconds("train", f"compiling\n{line}\n") == 6.5
    assert cc.command("train", 20)[-6:] == ["cpu", "--iterations", "20", "--repeats", "1", "--json"]


def test_the_alu_probe_runs_alone_and_paired() -> None:
    alone, (x, y) = cc.run("alu", 20_000, 1), cc.run("alu", 20_000, 2)
    assert 0 < alone[0] < 5 and 0 < x < 5 and 0 < y < 5
