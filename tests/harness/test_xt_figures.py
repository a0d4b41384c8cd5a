"""The x–t haze grid of a study report (``xt_grid``): from fake slice arrays, no training. One
figure per scene, a row per variant and a ground-truth row, a column per seed (at most five),
every difference panel on one colour scale with one colour bar, readable at a glance."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest

import harness.report.plots as plots
from harness.report import figure_checks, xt_figures
from harness.spec.study_schema import Plot

F, W = 30, 64


def fake_arrays(rng: np.random.Generator, haze: float) -> dict[str, np.ndarray]:
    """A slice whose render is the noise-free truth plus ``haze`` of noise; the recorded truth has σ = 0.01."""
    clean = np.broadcast_to(rng.integers(0, 256, (1, W, 3)), (F, W, 3)).astype(np.uint8)
    recorded = np.clip(np.round(clean + rng.normal(0, 2.55, clean.shape)), 0, 255).astype(np.uint8)
    render = np.clip(clean / 255.0 + rng.normal(0, haze, clean.shape), 0, 1).astype(np.float16)
    return {"render": render, "gt": recorded, "gt_clean": clean, "row": np.int64(12), "camera": np.str_("cam00"),
            "fps": np.float64(30.0)}


@pytest.fixture
def drawn(monkeypatch: pytest.MonkeyPatch) -> list[tuple[str, plt.Figure, list[str]]]:
    """Each figure the module saves, with its problems (checked before it is written)."""
    seen: list[tuple[str, plt.Figure, list[str]]] = []
    save = plots.save_figure

    def checked(fig: plt.Figure, path: Path) -> Path:
        images = [ax for ax in fig.axes if ax.get_visible() and ax.images]
        seen.append((path.name, images, figure_checks.figure_problems(fig)))
        return save(fig, path)

    monkeypatch.setattr(plots, "save_figure", checked)
    return seen


def test_the_difference_is_against_the_noise_free_truth() -> None:
    rng = np.random.default_rng(0)
    a = fake_arrays(rng, 0.0)
    a["render"] = (a["gt_clean"] / 255.0).astype(np.float16)  # a perfect render: no difference at all
    assert xt_figures.xt_difference(a).max() < 1e-3
    del a["gt_clean"]  # a scene without noise-free frames: against the recorded ones
    assert xt_figures.xt_difference(a).mean() == pytest.approx(
        np.abs(a["render"].astype(np.float32) - a["gt"] / 255.0).mean(), rel=1e-5)


def test_the_grid_has_a_row_per_variant_and_a_column_per_seed(tmp_path: Path, drawn: list) -> None:
    rng = np.random.default_rng(1)
    variants = {"mcmc": 0.002, "exact_copy": 0.02, "partial_copy": 0.005}
    rows = {v: {seed: xt_figures.xt_difference(fake_arrays(rng, haze)) for seed in (0, 1, 2, 3)}
            for v, haze in variants.items()}
    rows["partial_copy"][3] = None  # a run without arrays: its panel stays empty
    path = xt_figures.xt_grid_figure(rows, fake_arrays(rng, 0.0), "secret4: x–t slices", tmp_path / "xt_grid_s.png")
    assert path.is_file()
    (name, images, problems) = drawn[0]
    assert name == "xt_grid_s.png" and problems == []
    panels = [ax for ax in images if ax.images[0].get_cmap().name == "magma"]
    assert len(panels) == 3 * 4 - 1 + 1  # variants x seeds, less the missing run, plus the recorded noise
    assert {ax.images[0].get_clim() for ax in panels} == {panels[0].images[0].get_clim()}  # one colour scale
    assert panels[0].images[0].get_clim()[0] == 0.0
    assert len(images) - len(panels) == 1  # the noise-free ground truth itself, in colour
    fig = images[0].figure
    assert any(ax.get_label() == "<colorbar>" for ax in fig.axes)
    titles = [ax.get_title() for ax in images if ax.get_title().startswith("seed")]
    assert titles == ["seed 0", "seed 1", "seed 2", "seed 3"]
    assert [ax.get_ylabel().split("\n")[0] for ax in images if ax.get_subplotspec().colspan.start == 0] == [
        "mcmc", "exact_copy", "partial_copy", "ground truth"]
    # the hazy variant stands out on the shared scale
    mean = {v: np.nanmean([d.mean() for d in rows[v].values() if d is not None]) for v in rows}
    assert mean["exact_copy"] > 5 * mean["mcmc"]


def test_a_study_report_draws_one_grid_per_scene_from_the_runs_artifacts(tmp_path: Path, drawn: list) -> None:
    assert Plot("xt_grid") is Plot.xt_grid
    rng = np.random.default_rng(2)
    runs, arrays = [], {}
    for scene in ("studio", "long_slow"):
        for v in ("mcmc", "exact_copy"):
            for seed in range(6):
                run_id = f"{v}-{scene}-{seed}"
                runs.append({"variant": v, "scene": scene, "seed": seed, "status": "FINISHED", "run_id": run_id})
                arrays[run_id] = fake_arrays(rng, 0.01)
    runs.append({"variant": "mcmc", "scene": "studio", "seed": 6, "status": "FAILED", "run_id": "x"})

    def copy_artifacts(run_id: str, paths: list[str], folder: Path, under: str = "") -> list[Path]:
        assert paths == ["diagnostics/xt_slice.npz"] and under == "diagnostics"
        target = folder / "xt_slice.npz"
        np.savez(target, **arrays[run_id])
        return [target]

    df = pd.DataFrame(runs)
    data = SimpleNamespace(
        study=SimpleNamespace(name="secret4", plots=(Plot.strip, Plot.xt_grid)), store=SimpleNamespace(
            copy_artifacts=copy_artifacts), df=df, order=lambda: (["mcmc", "exact_copy"], ["studio", "long_slow"]),
        labels=lambda: {"studio": "studio", "long_slow": "long, slow (4 s)"}, filled=None)
    made = xt_figures.figures(data, tmp_path)
    assert [p.name for _, p in made] == ["xt_grid_studio.png", "xt_grid_long_slow.png"]
    assert all(p.is_file() for _, p in made) and all(problems == [] for _, _, problems in drawn)
    for _, images, _ in drawn:  # 2 variants x the first 5 seeds, and the recorded noise
        assert len([ax for ax in images if ax.images[0].get_cmap().name == "magma"]) == 2 * 5 + 1
    data.study.plots = (Plot.strip,)
    assert xt_figures.figures(data, tmp_path / "none") == []
