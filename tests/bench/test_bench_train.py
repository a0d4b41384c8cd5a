"""``ftgspp bench train`` runs every CPU backend through the real trainer and reports ratios."""

import json
import time

from ftgspp.bench import main


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


class Pipeline:
    """Two nested seams for the timer test."""

    @staticmethod
    def outer():
        time.sleep(0.02)
        Pipeline.inner()

    @staticmethod
    def inner():
        time.sleep(0.03)


def test_phase_timer_charges_exclusive_time_and_restores_the_seams():
    """Nested timed calls: the parent is charged its own time only; only the loop counts;
    the seams are unwrapped afterwards."""
    import ftgspp.bench.phases as bp
    import ftgspp.trainer as trainer

    seams = (("outer", f"{__name__}:Pipeline.outer"), ("inner", f"{__name__}:Pipeline.inner"))
    original_loop, original_outer = trainer._loop, Pipeline.__dict__["outer"]
    with bp.PhaseTimer(seams) as timer:
        Pipeline.outer()  # outside the trainer's loop: not counted
        assert dict(timer.totals) == {}
        timer._gate(Pipeline.outer)()
    assert 0.015 < timer.totals["outer"] < 0.029 and 0.025 < timer.totals["inner"]
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
