"""``study budget``: the smallest model within the SESOI of the best, settled over seeds.

The search (``analysis.budget_search.find``) is driven by curves of PSNR against the budget with
stated per-seed offsets; the oracles are the curves themselves (the budget where the true gap
plus the interval's half-width crosses the SESOI) and, for runs-needed, a simulation of the
equivalence test. One search goes through ``run_study`` with the fake trainer.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from fakes import fake_generate, fake_train
from scipy import stats

from ftgspp.bench.model_fps import MODEL_FILES
from ftgspp.errors import InputError
from harness.analysis.budget_search import (
    BudgetSearch,
    doubling_verdict,
    find,
    gain,
    midpoint,
    runs_needed,
    tost_power,
)
from harness.cli.budget import search, synthetic_scene
from harness.report.budget_page import write

SESOI = 0.2
OFFSETS = (-0.01, 0.0, 0.01)  # per-seed offsets: SD 0.01 dB, narrow intervals


def saturating_curve(budget: float) -> float:
    return 30.0 - 3.0 * math.exp(-budget / 1500)


def half_width(offsets: tuple[float, ...]) -> float:
    """The 90% Welch half-width of a difference of two budgets' means with these offsets each
    (equal spreads and sizes: 2n − 2 degrees of freedom)."""
    n, s = len(offsets), np.std(offsets, ddof=1)
    return float(stats.t.ppf(0.95, 2 * n - 2) * s * math.sqrt(2 / n))


def curve_measure(found: BudgetSearch, curve, offsets=OFFSETS):
    """``measure`` of the search on a curve: per-seed values curve(b) + offset, with the other
    columns the page shows (half the Gaussians drawn, 59 bytes each)."""
    def measure(budget: int) -> np.ndarray:
        if budget not in found.scores:
            found.scores[budget] = [curve(budget) + o for o in offsets]
            found.seconds[budget] = [1.0 + budget / 1000] * len(offsets)
            found.faded[budget] = [budget / 2] * len(offsets)
            found.alive[budget] = [budget / 2] * len(offsets)
            found.model_bytes[budget] = [59.0 * budget] * len(offsets)
        return np.array(found.scores[budget])
    return measure


def test_intervals_and_verdicts() -> None:
    g = gain([30.0, 30.1, 29.9], [30.5, 30.6, 30.4])
    oracle = stats.ttest_ind([30.5, 30.6, 30.4], [30.0, 30.1, 29.9], equal_var=False).confidence_interval(0.90)
    assert g.mean == pytest.approx(0.5) and (g.low, g.high) == pytest.approx((oracle.low, oracle.high))
    assert doubling_verdict(g, SESOI) == "gains"
    assert doubling_verdict(gain([30, 30.01, 29.99], [30.05, 30.06, 30.04]), SESOI) == "equivalent"
    assert doubling_verdict(gain([30, 31, 29], [30, 31, 29]), SESOI) == "unsettled"  # mean 0, interval wide
    assert doubling_verdict(gain([31, 31.01, 30.99], [30, 30.01, 29.99]), SESOI) == "loses"
    assert midpoint(1000, 2000) == 1500 and midpoint(1000, 1300) == 1200


def test_it_stops_on_a_saturating_curve_and_bisects_to_the_smallest_equivalent_budget() -> None:
    found = BudgetSearch("curve", SESOI)
    find(found, curve_measure(found, saturating_curve), start=500, max_budget=64_000)
    h = half_width(OFFSETS)
    # oracle: doubling stops at the first doubling whose true gain plus the half-width is under the SESOI
    doublings = [500 * 2**i for i in range(8)]
    stop = next(b for b in doublings if saturating_curve(2 * b) - saturating_curve(b) + h < SESOI)
    assert found.saturated and max(found.scores) == 2 * stop == 16_000  # never trained 32,000 or 64,000
    assert [s.split(":")[0] for s in found.steps if "->" in s.split(":")[0]][-1] == f"{stop} -> {2 * stop}"
    # oracle: the smallest budget whose true gap to the best plus the half-width is under the SESOI
    best = saturating_curve(found.best)
    smallest = -1500 * math.log((SESOI - h - (best - 30.0)) / 3.0)
    assert found.best == 16_000 and found.chosen < found.best
    assert smallest <= found.chosen <= smallest + max(found.chosen // 8, 100)
    assert found.settled and found.gap().settled_below(SESOI)
    assert found.seconds_saved() > 0


def test_it_does_not_stop_while_the_interval_is_wide_and_says_what_would_settle_it(tmp_path: Path) -> None:
    found = BudgetSearch("wide", SESOI)
    flat = lambda b: 30.0 - 3.0 * math.exp(-b / 300)  # noqa: E731 - saturated (< 0.001 dB a doubling) by 4,000
    find(found, curve_measure(found, flat, offsets=(-1.0, 0.0, 1.0)), start=500, max_budget=16_000)
    assert not found.saturated and max(found.scores) == 16_000 and found.chosen == found.best
    assert not any("equivalent" in s for s in found.steps) and sum("unsettled" in s for s in found.steps) >= 3
    # oracle: the normal approximation of the TOST's runs per arm, 2 (z_.95 + z_.90)² SD² / SESOI²
    approx = 2 * (stats.norm.ppf(0.95) + stats.norm.ppf(0.90)) ** 2 * 1.0**2 / SESOI**2
    assert approx <= found.runs_needed <= approx + 3
    md = write(found, tmp_path / "wide").read_text()
    assert "No settled answer up to 16,000 Gaussians" in md and f"{found.runs_needed:.0f} runs per budget" in md
    assert f"{found.best // 2:,} Gaussians drawn, {59 * found.best / 1e6:.2f} MB" in md  # the best's n_alive, bytes


def test_runs_needed_gives_the_power_a_simulated_equivalence_test_has() -> None:
    from statsmodels.stats.weightstats import ttost_ind

    n = int(runs_needed(SESOI, 0.2))
    rng = np.random.default_rng(5)

    def simulated(n: int, draws: int = 1500) -> float:
        a, b = rng.normal(size=(draws, n)) * 0.2, rng.normal(size=(draws, n)) * 0.2
        return float(np.mean([ttost_ind(x, y, -SESOI, SESOI, usevar="unequal")[0] < 0.05 for x, y in zip(a, b)]))

    assert tost_power(SESOI, 0.2, n) >= 0.8 > tost_power(SESOI, 0.2, n - 1)
    assert simulated(n) == pytest.approx(0.8, abs=0.05) and simulated(max(n // 2, 2)) < 0.6
    assert runs_needed(SESOI, 10.0) == math.inf and math.isnan(runs_needed(SESOI, 0.0))


def test_the_page_names_the_answer_its_interval_drawn_gaussians_and_bytes(tmp_path: Path) -> None:
    found = BudgetSearch("curve", SESOI)
    find(found, curve_measure(found, saturating_curve), start=500, max_budget=64_000)
    md = write(found, tmp_path / "curve", true_size=500).read_text()
    assert f"**Smallest sufficient budget: {found.chosen:,} Gaussians** ({found.chosen // 2:,} Gaussians drawn," \
           f" {59 * found.chosen / 1e6:.2f} MB)" in md and ", settled;" in md
    assert "| Gaussians drawn (n_alive) |" in md and "model size (MB)" in md
    import pandas as pd

    csv = pd.read_csv(tmp_path / "curve" / "budget.csv")
    assert {"n_alive", "model_bytes", "gap_low", "gap_high", "chosen", "saturated", "settled", "true_size"} <= set(csv)
    assert csv.settled.all() and csv[csv.chosen].budget.item() == found.chosen


def fake_with_size(cfg, out_dir, tracker):
    """The saturating curve, half the Gaussians drawn nowhere, and a model file of 59 bytes a Gaussian."""
    result = fake_train(cfg, out_dir, tracker)
    result.metrics["psnr"] = saturating_curve(cfg.budget) + OFFSETS[cfg.seed % 3]
    result.metrics["n_faded"] = cfg.budget / 2
    result.metrics["train_seconds"] = 1.0 + cfg.budget / 1000
    (Path(out_dir) / MODEL_FILES[0]).write_bytes(b"\0" * (59 * cfg.budget))
    return result


def test_the_study_search_trains_what_it_decides_and_resumes(workdir: Path) -> None:
    kw = dict(start=2000, max_budget=16_000, seeds=3, train_fn=fake_with_size, generate=fake_generate,
              echo=lambda s: None)
    found = search(synthetic_scene("static"), control=500, **kw)
    assert found.sesoi == SESOI  # the registry's SESOI of psnr
    assert found.saturated and found.best == 16_000 and 4000 < found.chosen < 8000 and found.settled
    assert found.alive[found.chosen] == [found.chosen / 2] * 3  # n_gaussians − n_faded
    assert found.model_bytes[found.chosen] == [59 * found.chosen] * 3  # the model file in each run's folder
    assert len(found.control) == 3  # the control variant trained beside the search
    md = write(found, Path("outputs/reports/budget") / found.scene).read_text()
    assert "Started from the true K Gaussians" in md
    again = search(synthetic_scene("static"), **kw)
    assert again.chosen == found.chosen and again.scores == found.scores  # resumed from the store
    with pytest.raises(InputError, match="--metric"):
        search(synthetic_scene("plain"), metric="lpips_alex", train_fn=fake_with_size, generate=fake_generate)


def test_the_known_size_preset_is_noisy_and_the_noise_free_scene_keeps_its_name() -> None:
    noisy, clean = synthetic_scene("known_size"), synthetic_scene("known_size", noise_sd=0)
    assert noisy.synth == {"preset": "known_size", "seed": 0, "layout": "dynerf", "noise_sd": 2.0}
    assert noisy.name == "budget_known_size_noise2" and noisy.synth_dir.endswith("budget_known_size_noise2")
    # the committed runs' scene: the same name and generator arguments, so the same config hashes
    assert clean.name == "budget_known_size" and clean.synth == {"preset": "known_size", "seed": 0, "layout": "dynerf"}
    assert synthetic_scene("static").synth == {"preset": "static", "seed": 0, "layout": "dynerf"}
    with pytest.raises(InputError, match="--noise-sd"):
        synthetic_scene("static", noise_sd=2)


def test_the_command_line_names_the_noise_and_refuses_bad_arguments(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                    capsys: pytest.CaptureFixture) -> None:
    from harness.cli import budget as cli_budget
    from harness.cli.study import main

    asked = {}

    def fake_search(scene, **kw):
        asked.update(kw, scene=scene)
        found = BudgetSearch(scene.name, kw["sesoi"] or SESOI)
        return find(found, curve_measure(found, saturating_curve), kw["start"], kw["max_budget"])

    monkeypatch.setattr(cli_budget, "search", fake_search)
    assert main(["budget", "--preset", "known_size", "--control", "--out", str(tmp_path)]) == 0
    assert asked["scene"].name == "budget_known_size_noise2" and asked["control"] == 500  # K of the preset
    md = (tmp_path / "budget_known_size_noise2" / "budget.md").read_text()
    assert "`study budget --preset known_size --noise-sd 2 --control --start 500" in md and "--sesoi 0.2" in md
    assert "Smallest sufficient budget" in capsys.readouterr().out
    for bad in (["--control"], ["--noise-sd", "-1"], ["--sesoi", "0"]):
        preset = "static" if bad == ["--control"] else "known_size"
        with pytest.raises(SystemExit) as stop:
            main(["budget", "--preset", preset, *bad, "--out", str(tmp_path)])
        assert stop.value.code == 2
