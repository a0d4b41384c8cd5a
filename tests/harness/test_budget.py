"""``study budget``: doubling then bisection finds the smallest sufficient budget of a scene."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from fakes import fake_generate, fake_train

from ftgspp.errors import InputError
from harness.analysis.budget_search import gain, midpoint, sufficient
from harness.cli.budget import search, synthetic_scene
from harness.report.budget_page import write


def saturating(cfg, out_dir, tracker):
    """PSNR rises with the budget and saturates: 30 - 3 exp(-budget / 1500), plus seed noise."""
    result = fake_train(cfg, out_dir, tracker)
    result.metrics["psnr"] = 30.0 - 3.0 * math.exp(-cfg.budget / 1500) + 0.01 * (cfg.seed - 1)
    # colour-aligned: the held-out camera's colour error gone, the model keeps gaining longer
    result.metrics["psnr_cc"] = 34.0 - 6.0 * math.exp(-cfg.budget / 6000) + 0.01 * (cfg.seed - 1)
    result.metrics["train_seconds"] = 1.0 + cfg.budget / 1000
    return result


def test_gain_and_decisions() -> None:
    g = gain([30.0, 30.1, 29.9], [30.5, 30.6, 30.4])
    assert g.mean == 0.5 and g.low < 0.5 < g.high and not g.settled_below(0.1)
    assert sufficient([30.45], [30.5], 0.1) and not sufficient([30.3], [30.5], 0.1)
    assert midpoint(1000, 2000) == 1500 and midpoint(1000, 1300) == 1200


def test_the_search_doubles_then_bisects_and_reports_the_time_saved(workdir: Path) -> None:
    found = search(synthetic_scene("static"), start=500, max_budget=64_000, threshold=0.1, seeds=3,
                   train_fn=saturating, generate=fake_generate, echo=lambda s: None)
    # 30 - 3 exp(-b/1500): the gain of doubling falls under 0.1 dB between 4000 and 8000
    doubled = [step.split(":")[0] for step in found.steps if "->" in step.split(":")[0]]
    assert found.saturated and doubled == ["500 -> 1000", "1000 -> 2000", "2000 -> 4000", "4000 -> 8000",
                                           "8000 -> 16000"]
    assert 4000 < found.chosen <= 8000 and found.chosen < found.best
    assert 3.0 * math.exp(-found.chosen / 1500) - 3.0 * math.exp(-found.best / 1500) < 0.1  # truly sufficient
    assert found.seconds_saved() > 0 and found.gap().mean < 0.1
    md = write(found, Path("outputs/reports/budget") / found.scene).read_text()
    assert f"**Smallest sufficient budget: {found.chosen} Gaussians**" in md and "saves" in md
    again = search(synthetic_scene("static"), start=500, max_budget=64_000, threshold=0.1, seeds=3,
                   train_fn=saturating, generate=fake_generate, echo=lambda s: None)
    assert again.chosen == found.chosen  # resumed from the store: the same answer


def test_no_saturation_is_said_plainly(workdir: Path) -> None:
    found = search(synthetic_scene("studio"), start=500, max_budget=2000, threshold=0.001, seeds=2,
                   train_fn=saturating, generate=fake_generate, echo=lambda s: None)
    assert not found.saturated and found.chosen == 2000
    md = write(found, Path("outputs/reports/budget") / found.scene).read_text()
    assert "No saturation" in md


def test_the_colour_aligned_psnr_is_searched_on_its_own_values(workdir: Path) -> None:
    raw = search(synthetic_scene("plain"), start=500, max_budget=256_000, threshold=0.1, seeds=2,
                 train_fn=saturating, generate=fake_generate, echo=lambda s: None)
    cc = search(synthetic_scene("plain"), start=500, max_budget=256_000, threshold=0.1, seeds=2,
                train_fn=saturating, generate=fake_generate, echo=lambda s: None, metric="psnr_cc")
    # 6 exp(-b/6000) - 6 exp(-2b/6000) < 0.1 needs b > ~24,500; the raw curve saturates near 6,000
    assert raw.chosen <= 8000 < 16_000 < cc.chosen <= 32_000 and cc.saturated
    assert 6.0 * math.exp(-cc.chosen / 6000) - 6.0 * math.exp(-cc.best / 6000) < 0.1
    md = write(cc, Path("outputs/reports/budget_cc") / cc.scene).read_text()
    assert "colour-aligned held-out PSNR (`psnr_cc`)" in md and "| PSNR colour-aligned (dB) |" in md
    with pytest.raises(InputError, match="--metric"):
        search(synthetic_scene("plain"), metric="lpips_alex", train_fn=saturating, generate=fake_generate)
