"""``ftgspp bench train`` runs every CPU backend through the real trainer and reports ratios;
``PhaseTimer`` charges exclusive time per phase; ``bench scale`` fits its exponents.

Timings are printed, never asserted: these tests check the output's shape, tables and
parsing, and drive ``PhaseTimer`` with a fake clock.
"""

import json
import types

import pytest

from ftgspp.bench import main
from ftgspp.bench.train_speed import format_train_table
from ftgspp.errors import InputError


def test_bench_train_json(capsys):
    assert main(["train", "--iterations", "4", "--budget", "200", "--repeats", "1",
                 "--width", "64", "--height", "48", "--json"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert set(out["backends"]) == {"reference", "cpu"}
    for r in out["backends"].values():
        assert r["ms_per_iter"] > 0 and len(r["all_ms"]) == 1
    assert out["speedup_vs_reference"]["reference"] == 1.0


def test_breakdown_covers_the_pipeline_and_adds_up(capsys):
    """Every phase of the cpu path is timed, and the phases sum to the loop's own clock."""
    assert main(["train", "--iterations", "6", "--budget", "200", "--repeats", "1", "--width", "64",
                 "--height", "48", "--backends", "cpu,reference", "--breakdown", "--json"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    cpu, ref = out["breakdown"]["cpu"], out["breakdown"]["reference"]
    for phase in ("prepare forward (time + SH + projection)", "prepare backward", "rasterize forward",
                  "rasterize backward", "loss forward", "backward (rest)", "optimizer", "other (Python, glue)"):
        assert phase in cpu, phase
    for phase in ("model at time t", "projection", "SH colour", "rasterize forward"):
        assert phase in ref and ref[phase] > 0, phase
    assert all(v >= 0 for k, v in cpu.items() if k != "other (Python, glue)")
    lines = format_train_table(out).splitlines()  # the table: one row per backend, one per phase, a total
    assert lines[0].startswith("training iteration, 200 Gaussians, 64x48, 6 iterations x 1 repeats")
    assert lines[1].startswith("host ") and "Numba kernels for" in lines[1]  # the ISA it ran with
    assert [line.split()[0] for line in lines[3:5]] == ["cpu", "reference"] and lines[4].split()[-1] == "1.0x"
    assert lines[6].startswith("per-phase ms per iteration") and lines[7].split()[1:] == ["cpu", "reference"]
    n_phase_lines = 8 + len(set(cpu) | set(ref)) + 1
    assert lines[n_phase_lines - 1].startswith("total")
    # the rasterizer's work: counted on the cpu backend only (the reference renderer has no tiles)
    assert set(out["work"]) == {"cpu"}
    work = out["work"]["cpu"]
    assert 0 < work["Gaussians drawn"] <= 200  # the budget
    assert work["Gaussians drawn"] <= work["tile pairs"] and 0 < work["live pairs"] <= work["tile pairs"]
    assert work["slots per pixel"] > 0 and work["rasterize ns per pixel slot"] > 0
    assert lines[n_phase_lines + 1].startswith("cpu rasterizer work per rendered view")
    assert len(lines) == n_phase_lines + 3 + len(work)


class Pipeline:
    """Two nested seams for the timer test; each advances the fake clock by its own time."""

    clock = 0.0

    @staticmethod
    def outer():
        Pipeline.clock += 0.02
        Pipeline.inner()

    @staticmethod
    def inner():
        Pipeline.clock += 0.03


def test_phase_timer_charges_exclusive_time_and_restores_the_seams(monkeypatch):
    """Nested timed calls: the parent is charged its own time only; only the loop counts;
    the seams are unwrapped afterwards."""
    import ftgspp.bench.phases as bp
    import ftgspp.trainer as trainer

    monkeypatch.setattr(bp, "time", types.SimpleNamespace(perf_counter=lambda: Pipeline.clock))
    seams = (("outer", f"{__name__}:Pipeline.outer"), ("inner", f"{__name__}:Pipeline.inner"))
    original_loop, original_outer = trainer._loop, Pipeline.__dict__["outer"]
    with bp.PhaseTimer(seams) as timer:
        Pipeline.outer()  # outside the trainer's loop: not counted
        assert dict(timer.totals) == {}
        timer._gate(Pipeline.outer)()
    assert timer.totals["outer"] == pytest.approx(0.02) and timer.totals["inner"] == pytest.approx(0.03)
    assert timer.loop_seconds == pytest.approx(0.05) and dict(timer.calls) == {"outer": 1, "inner": 1}
    ms = timer.per_iteration(1)
    assert abs(sum(ms.values()) - 1000 * timer.loop_seconds) < 1e-6
    assert trainer._loop is original_loop and Pipeline.__dict__["outer"] is original_outer


def test_fit_recovers_planted_exponents():
    from ftgspp.bench.scale import fit_exponents

    points = [{"n": n, "pixels": p, "ms_per_iter": 0.002 * n**0.8 * p**0.5} for n in (1e3, 5e3, 2e4)
              for p in (12288, 49152)]
    fit = fit_exponents(points)
    assert abs(fit["exponent_n"] - 0.8) < 1e-9 and abs(fit["exponent_pixels"] - 0.5) < 1e-9
    assert abs(fit["a_ms"] - 0.002) < 1e-9


def test_scale_sizes_are_parsed_before_anything_runs():
    with pytest.raises(InputError, match="--sizes.*WxH"):
        main(["scale", "--sizes", "128x96,256"])


def test_bench_train_times_each_method_and_its_ratio_to_the_first(capsys):
    assert main(["train", "--iterations", "3", "--budget", "200", "--repeats", "1", "--width", "64",
                 "--height", "48", "--backends", "cpu", "--models", "ftgs,stg", "--json"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert set(out["backends"]) == {"ftgs/cpu", "stg/cpu"} and out["models"] == ["ftgs", "stg"]
    ratio = out["ratio_vs_first_model"]
    assert ratio["ftgs/cpu"] == 1.0
    assert ratio["stg/cpu"] == out["backends"]["stg/cpu"]["ms_per_iter"] / out["backends"]["ftgs/cpu"]["ms_per_iter"]
    lines = format_train_table(out).splitlines()
    assert lines[2].split()[-2:] == ["vs", "ftgs"] and lines[3].split()[0] == "ftgs/cpu" and lines[3].endswith("1.00x")
    with pytest.raises(InputError, match="no model 'nope'"):
        main(["train", "--iterations", "3", "--models", "nope"])


def test_bench_train_after_times_only_the_resumed_iterations(monkeypatch, capsys):
    """``--after N``: each row trains its first N iterations once, untimed, and every timed run
    resumes a copy of that checkpoint; the figure is the resumed part's own loop seconds."""
    import ftgspp.trainer as trainer
    from ftgspp.train_state import TrainState

    real_train, real_load = trainer.train, TrainState.load
    calls, resumed_at = [], []

    def load(self, path):  # the step every timed run starts from
        ok = real_load(self, path)
        resumed_at.append(self.step)
        return ok

    def train(cfg, scene, tracker=None):
        result = real_train(cfg, scene, tracker)
        calls.append((cfg.iterations, cfg.resume, cfg.strategy.refine_stop_iter, result.metrics["train_seconds"]))
        return result

    monkeypatch.setattr(trainer, "train", train)
    monkeypatch.setattr(TrainState, "load", load)
    assert main(["train", "--iterations", "4", "--budget", "200", "--repeats", "2", "--width", "64",
                 "--height", "48", "--backends", "cpu", "--after", "6", "--json"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["after"] == 6 and out["iterations"] == 4
    prefix, *timed = calls  # the prefix once, then the warm-up's 3 iterations and the 2 repeats' 4
    assert prefix[:3] == (6, False, 11)  # its relocation window is the timed runs' (6 + 4 + 1)
    assert [c[:3] for c in timed] == [(9, True, 11), (10, True, 11), (10, True, 11)]
    assert resumed_at == [6, 6, 6]  # every timed run started from the prefix's checkpoint
    expected = [1000.0 * (c[3] - prefix[3]) / 4 for c in timed[1:]]
    assert out["backends"]["cpu"]["all_ms"] == expected and all(ms > 0 for ms in expected)
    assert "4 iterations after the first 6 x 2 repeats" in format_train_table(out).splitlines()[0]
    with pytest.raises(InputError, match="--after: must be 0 or more"):
        main(["train", "--after", "-1"])
