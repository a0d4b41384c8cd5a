"""Every report figure is readable at a glance: at most ~2,000 px wide and no two texts
overlapping (harness/report/figure_checks.py), on crowded inputs and on the committed reports."""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest

import harness.report.plots as plots
from harness.report import figure_checks, forest, ladder_figures, pareto_plots
from harness.spec.study_files import load_study

REPORTS = Path(__file__).resolve().parents[2] / "reports"


@pytest.fixture
def drawn(monkeypatch: pytest.MonkeyPatch) -> list[tuple[str, list[str]]]:
    """Each figure the report code saves, with its problems. The check draws the figure as it will be
    saved (120 dpi); the figure is then closed unwritten: writing the PNG would draw it twice more
    (``bbox_inches="tight"``) and nothing here reads the file (tests/harness/test_study_e2e.py does)."""
    seen: list[tuple[str, list[str]]] = []

    def checked(fig: plt.Figure, path: Path) -> Path:
        seen.append((path.name, figure_checks.figure_problems(fig)))
        plt.close(fig)
        return path

    monkeypatch.setattr(plots, "save_figure", checked)
    monkeypatch.setattr(forest, "save_figure", checked)
    monkeypatch.setattr(ladder_figures, "save_figure", checked)
    monkeypatch.setattr(pareto_plots, "save_figure", checked)
    return seen


def test_the_check_finds_a_wide_figure_and_overlapping_labels() -> None:
    fig, ax = plt.subplots(figsize=(30, 3))
    ax.text(0.5, 0.5, "one label")
    ax.text(0.5, 0.5, "another label")
    problems = figure_checks.figure_problems(fig)
    plt.close(fig)
    assert any("px wide" in p for p in problems)
    assert "text 'one label' overlaps 'another label'" in problems
    fig, ax = plt.subplots(figsize=(6, 3))
    ax.plot([0, 1], [0, 1])
    assert figure_checks.figure_problems(fig) == []  # ticks outside the view are not drawn text
    plt.close(fig)


def test_crowded_strip_and_stability_figures_stay_readable(tmp_path: Path, drawn: list) -> None:
    rng = np.random.default_rng(0)
    variants = [f"stride{k}" for k in (1, 2, 4, 5, 8, 10, 20)] + ["prior_indoor", "prior_outdoor"]
    scenes = ["long_slow", "short_fast", "long_slow_b20k", "short_fast_b20k", "studio", "closed_window", "extra"]
    rows = [{"variant": v, "scene": s, "seed": k, "status": "FINISHED" if k else "FAILED", "psnr": 28 + rng.normal()}
            for s in scenes for v in (variants[:4] if "long" in s else variants[4:]) for k in range(3)]
    plots.strip_plot(pd.DataFrame(rows), "psnr", variants, scenes, {}, "strip", tmp_path / "strip.png")
    cells = [f"cell_with_a_long_name_{k}" for k in range(11)]
    st = pd.DataFrame([{"variant": v, "scene": c, "mean": 28.0, "std": 0.3, "spread": 0.5,
                        "failure_rate": 1.0 if k % 3 == 0 else np.nan if k % 3 == 1 else 0.5}
                       for k, c in enumerate(cells) for v in ("baseline", "ftgspp", "no_cc", "no_gate", "no_flow")])
    plots.stability_plot(st, list(dict.fromkeys(st.variant)), cells, {}, "stability", tmp_path / "stability.png")
    assert [name for name, _ in drawn] == ["strip.png", "stability.png"]
    assert all(problems == [] for _, problems in drawn), drawn


def test_the_committed_reports_figures_are_readable(tmp_path: Path, drawn: list) -> None:
    from harness.analysis import aggregate, speed_accuracy_scenes as sas

    for study in sorted(p.parent.name for p in REPORTS.glob("*/runs.csv")):
        df = pd.read_csv(REPORTS / study / "runs.csv")
        plots.strip_plot(df, "psnr", list(dict.fromkeys(df.variant)), list(dict.fromkeys(df.scene)), {}, study,
                         tmp_path / f"{study}_strip.png")
    df = pd.read_csv(REPORTS / "stability" / "runs.csv")
    plots.stability_plot(aggregate.stability(df), list(dict.fromkeys(df.variant)), list(dict.fromkeys(df.scene)), {},
                         "stability", tmp_path / "stability.png")
    for study in ("stability", "collapse"):
        (tmp_path / study).mkdir()
        ladder_figures.write(pd.read_csv(REPORTS / study / "runs.csv"), load_study(study).profiles["quick"].scenes,
                             tmp_path / study, study)
    df = pd.read_csv(REPORTS / "speed_accuracy" / "runs.csv")
    sa = sas.per_scene(df)
    plots.speed_accuracy_scenes_plot(sa, sas.smallest_per_scene(sa, df), "speed", tmp_path / "speed_accuracy.png")
    pareto_plots.pareto_plot(sa, "psnr", "speed", tmp_path / "pareto.png")
    forest.forest_plot(pd.read_csv(REPORTS / "claims.csv"), tmp_path / "forest.png")
    assert len(drawn) >= 17
    bad = [(name, problems) for name, problems in drawn if problems]
    assert bad == []


def test_a_full_two_method_pareto_grid_stays_readable(tmp_path: Path, drawn: list) -> None:
    from harness.analysis import speed_accuracy_scenes as sas

    rng = np.random.default_rng(1)
    rows = [{"variant": f"{m}_b{b}_i{i}", "scene": s, "scene_label": f"{s} (a long scene label)", "seed": k,
             "budget": float(b), "iterations": float(i), "status": "FINISHED", "psnr": 28 + rng.normal(),
             "train_seconds": b * i / 1e5, "n_gaussians": float(b), "n_faded": 0.2 * b,
             "render_fps_1thread": 1e5 / b, "model_bytes": 250.0 * b}
            for s in ("static", "studio", "fast_motion", "plain") for m in ("ftgs", "ftgspp")
            for b, i in ((500, 1000), (1500, 1000), (5000, 1000), (500, 3000), (1500, 3000), (5000, 3000),
                         (10000, 3000), (20000, 3000)) for k in range(3)]
    pareto_plots.pareto_plot(sas.per_scene(pd.DataFrame(rows)), "psnr", "speed_accuracy: PSNR against cost",
                             tmp_path / "pareto.png")
    assert [(name, problems) for name, problems in drawn] == [("pareto.png", [])]
