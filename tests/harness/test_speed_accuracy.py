"""Per-scene speed against accuracy on constructed runs whose answer is planted.

Three scenes: on ``static`` the smallest budget is 0.05 dB below the best (within the SESOI, 0.2 dB,
but three noisy seeds cannot settle it); on ``studio`` the smallest budget is 0.02 dB below
with almost no noise (settled); on ``fast`` only the largest budget is within 0.2 dB. The
Welch interval is checked against a hand computation (Welch-Satterthwaite degrees of freedom).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from harness.analysis import aggregate
from harness.analysis.speed_accuracy_scenes import per_scene, smallest_per_scene
from harness.report import plots
from harness.report.speed_accuracy_text import markdown, pair_sentences, report_markdown

LABELS = {"static": "Static", "studio": "Studio", "fast": "Fast motion"}
# (scene, variant) -> PSNR per seed, None = a failed run; absent pairs were never planned.
PSNR = {
    ("static", "b500_i1000"): [30.00, 30.20, 30.05],  # mean 30.0833, 0.05 below the best
    ("static", "b1000_i1000"): [30.10, 30.25, 30.05],  # mean 30.1333: best
    ("static", "b5000_i1000"): [30.08, 30.12, 30.10],  # mean 30.10
    ("static", "b2500_i1000"): [29.00, 29.10, 29.20],  # only on static
    ("studio", "b500_i1000"): [28.480, 28.482],  # mean 28.481, 0.02 below the best
    ("studio", "b1000_i1000"): [28.500, 28.502],  # mean 28.501: best
    ("studio", "b5000_i1000"): [28.490, 28.492],
    ("fast", "b500_i1000"): [24.0, 24.2],
    ("fast", "b1000_i1000"): [25.0, 25.4],
    ("fast", "b5000_i1000"): [26.0, 26.3],  # best, and the only one within 0.2 dB
    ("fast", "b5000_i300"): [None, None],  # every run failed
}


def _budget_iterations(variant: str) -> tuple[float, float]:
    b, i = variant.split("_")
    return float(b[1:]), float(i[1:])


def _frame(psnr: dict[tuple[str, str], list[float | None]] = PSNR) -> pd.DataFrame:
    """One row per planned run, as ``aggregate.runs_frame`` makes them."""
    rows = []
    for (scene, variant), values in psnr.items():
        budget, iterations = _budget_iterations(variant)
        for seed, x in enumerate(values):
            rows.append({
                "variant": variant, "scene": scene, "seed": seed, "config_hash": f"{variant}{scene}{seed}",
                "scene_label": LABELS.get(scene, scene), "budget": budget, "iterations": iterations,
                "status": "FAILED" if x is None else "FINISHED", "failure": "", "error": "", "run_id": "r",
                "psnr": math.nan if x is None else x,
                "train_seconds": math.nan if x is None else iterations * (1 + budget / 1000) / 100 + 0.01 * seed,
                "n_gaussians": math.nan if x is None else budget,
            })
    return pd.DataFrame(rows)


def _values(scene: str, variant: str) -> np.ndarray:
    return np.array([x for x in PSNR[(scene, variant)] if x is not None])


def test_one_row_per_scene_and_variant_that_ran_missing_cells_absent() -> None:
    sa = per_scene(_frame())
    assert len(sa) == len(PSNR)
    assert ("fast", "b2500_i1000") not in set(zip(sa.scene, sa.variant))  # never planned on fast
    cells = sa.set_index(["scene", "variant"])
    for (scene, variant), values in PSNR.items():
        x = np.array([v for v in values if v is not None])
        row = cells.loc[(scene, variant)]
        assert (row.n, row.n_failed) == (len(x), len(values) - len(x))
        assert (row.budget, row.iterations) == _budget_iterations(variant)
        if len(x) == 0:
            assert math.isnan(row["mean"]) and not row.pareto_time and not row.pareto_gaussians
            continue
        assert row["mean"] == pytest.approx(x.mean())
        assert row["std"] == pytest.approx(x.std(ddof=1))
        lo, hi = stats.t.interval(0.95, len(x) - 1, loc=x.mean(), scale=x.std(ddof=1) / math.sqrt(len(x)))
        assert row.ci95 == pytest.approx((hi - lo) / 2, rel=1e-10)
    assert cells.loc[("studio", "b500_i1000"), "scene_label"] == "Studio"


def test_a_single_run_has_no_confidence_interval() -> None:
    sa = per_scene(_frame({("s", "b500_i1000"): [30.0], ("s", "b1000_i1000"): [30.5, 30.7]}))
    assert math.isnan(sa.set_index("variant").loc["b500_i1000", "ci95"])


def test_pareto_fronts_are_computed_within_each_scene() -> None:
    # On scene a, x and y trade time for quality; scene b's z is faster and better than both,
    # so pooled over scenes neither would be on the front.
    runs = _frame({("a", "b500_i1000"): [20.0, 20.0], ("a", "b5000_i1000"): [25.0, 25.0],
                   ("b", "b500_i300"): [30.0, 30.0], ("b", "b5000_i300"): [10.0, 10.0]})
    sa = per_scene(runs)
    pooled = aggregate.pareto_mask(sa.train_seconds.to_numpy(), sa["mean"].to_numpy())
    assert pooled.tolist() == [False, False, True, False]
    front = sa.set_index(["scene", "variant"])
    assert front.loc[("a", "b500_i1000"), "pareto_time"] and front.loc[("a", "b5000_i1000"), "pareto_time"]
    assert front.loc[("a", "b500_i1000"), "pareto_gaussians"] and front.loc[("a", "b5000_i1000"), "pareto_gaussians"]
    assert front.loc[("b", "b500_i300"), "pareto_time"] and not front.loc[("b", "b5000_i300"), "pareto_time"]
    assert not front.loc[("b", "b5000_i300"), "pareto_gaussians"]


def test_smallest_budget_per_scene_is_the_planted_one() -> None:
    df = _frame()
    chosen = smallest_per_scene(per_scene(df), df, tol_db=0.1).set_index("scene")
    assert chosen.index.tolist() == ["static", "studio", "fast"]
    assert chosen.loc["static", "variant"] == "b500_i1000" and chosen.loc["static", "best_variant"] == "b1000_i1000"
    assert chosen.loc["studio", "variant"] == "b500_i1000"
    assert chosen.loc["fast", "variant"] == "b5000_i1000" == chosen.loc["fast", "best_variant"]
    assert chosen.loc["static", "gap"] == pytest.approx(_values("static", "b1000_i1000").mean()
                                                        - _values("static", "b500_i1000").mean())
    assert chosen.loc["fast", "gap"] == 0 and chosen.loc["fast", "gap_ci95"] == 0
    assert chosen.loc["static", "mean"] == pytest.approx(_values("static", "b500_i1000").mean())
    # tighter tolerance: static's 0.05 dB gap no longer qualifies; the next budget is the best
    tight = smallest_per_scene(per_scene(df), df, tol_db=0.04).set_index("scene")
    assert tight.loc["static", "variant"] == "b1000_i1000"


def _welch_half_width(a: np.ndarray, b: np.ndarray) -> float:
    va, vb = a.var(ddof=1) / len(a), b.var(ddof=1) / len(b)
    dof = (va + vb) ** 2 / (va**2 / (len(a) - 1) + vb**2 / (len(b) - 1))
    return stats.t.ppf(0.975, dof) * math.sqrt(va + vb)


def test_gap_ci_is_welchs_and_says_whether_within_a_tenth_is_settled() -> None:
    df = _frame()
    chosen = smallest_per_scene(per_scene(df), df, tol_db=0.1).set_index("scene")
    for scene in ("static", "studio"):
        best, pick = _values(scene, "b1000_i1000"), _values(scene, "b500_i1000")
        assert chosen.loc[scene, "gap_ci95"] == pytest.approx(_welch_half_width(best, pick), rel=1e-10)
    assert chosen.loc["static", "gap_ci95"] > 0.05  # 0.05 +- more than 0.05 reaches 0.1: not settled
    assert chosen.loc["static", "gap_ci_includes_tol"]
    assert not chosen.loc["studio", "gap_ci_includes_tol"]  # 0.02 +- ~0.006: settled
    assert not chosen.loc["fast", "gap_ci_includes_tol"]  # the best itself: gap exactly 0


def test_gap_ci_is_missing_with_fewer_than_two_runs() -> None:
    df = _frame({("s", "b500_i1000"): [30.0, None], ("s", "b1000_i1000"): [30.05, 30.06]})
    chosen = smallest_per_scene(per_scene(df), df).iloc[0]
    assert chosen.variant == "b500_i1000"
    assert math.isnan(chosen.gap_ci95) and pd.isna(chosen.gap_ci_includes_tol)


def test_markdown_table_and_scene_comparisons_come_from_the_data() -> None:
    df = _frame()
    chosen = smallest_per_scene(per_scene(df), df)
    assert pair_sentences(chosen) == [
        "Static and Studio both need 500 Gaussians; not settled for Static (the gap's CI reaches the tolerance).",
        # fast motion is best at its largest budget: the grid shows no saturation there
        "Static needs 500 Gaussians; Fast motion still gains at 5000, its largest budget tried; not settled for"
        " Static (the gap's CI reaches the tolerance).",
        "Studio needs 500 Gaussians; Fast motion still gains at 5000, its largest budget tried.",
    ]
    fast = next(row for row in markdown(chosen).splitlines() if row.startswith("| Fast motion |"))
    assert fast.endswith("| — (the largest budget tried: no saturation within the grid) |")
    table = markdown(chosen).splitlines()
    assert len([row for row in table if row.startswith("| ")]) == 1 + 3  # header + one row per scene
    static = next(row for row in table if row.startswith("| Static |"))
    assert "500 (`b500_i1000`)" in static and "`b1000_i1000`" in static and "30.08 ±" in static
    section = report_markdown(df)
    assert section.startswith("### Smallest budget within 0.2 dB of the best, per scene")
    assert "No finished runs" not in section


def test_per_scene_figure_is_written(tmp_path: Path) -> None:
    df = _frame()
    sa = per_scene(df)
    path = plots.speed_accuracy_scenes_plot(sa, smallest_per_scene(sa, df), "test", tmp_path / "sa.png")
    assert path.is_file() and path.stat().st_size > 10_000


def _study():
    """A three-scene study whose scenes run their own seeds and variant subsets, as in ``PSNR``."""
    from harness.spec.study_files import parse_study

    variants = {v: [f"budget={v.split('_')[0][1:]}", f"iterations={v.split('_')[1][1:]}"]
                for v in ("b500_i1000", "b1000_i1000", "b2500_i1000", "b5000_i1000", "b5000_i300")}
    synth = {"preset": "studio", "seed": 0}
    scenes = [
        {"name": "static", "label": "Static", "synth": synth, "seeds": 3,
         "variants": ["b500_i1000", "b1000_i1000", "b2500_i1000", "b5000_i1000"]},
        {"name": "studio", "label": "Studio", "synth": synth, "variants": ["b500_i1000", "b1000_i1000", "b5000_i1000"]},
        {"name": "fast", "label": "Fast motion", "synth": synth,
         "variants": ["b500_i1000", "b1000_i1000", "b5000_i1000", "b5000_i300"]},
    ]
    raw = {"name": "sa3", "question": "What does each scene need?", "baseline": "b5000_i1000",
           "variants": variants, "plots": ["speed_accuracy"], "table": {"layout": "variants_x_metrics"},
           "profiles": {"quick": {"seeds": 2, "scenes": scenes}, "paper": {"seeds": 2, "scenes": scenes}}}
    return parse_study(raw, Path("sa3.yaml"))


def test_multi_scene_report_writes_the_per_scene_csv_figure_and_section(tmp_path: Path) -> None:
    from harness.report.results import ReportData
    from harness.report.sections import TablesSection, figures
    from harness.report.writer import study_page
    from harness.spec.runs import Selection, expand

    study, df = _study(), _frame()
    planned = {(r.variant, r.scene.name, r.seed) for r in expand(study, Selection())}
    assert planned == set(zip(df.variant, df.scene, df.seed))  # the planted cells are what the planner makes
    data = ReportData(study, Selection(), [], df, "sqlite:///mlflow.db", "ftgspp/sa3", [], None)
    made = figures(data, tmp_path)
    (tmp_path / "index.md").write_text(study_page(data, tmp_path, TablesSection([], {}, "", ""), [], made, []))
    assert [p.name for _, p in made] == ["speed_accuracy.png"]
    sa = pd.read_csv(tmp_path / "speed_accuracy.csv")
    assert len(sa) == len(PSNR) and set(sa.scene) == set(LABELS)
    smallest = pd.read_csv(tmp_path / "speed_accuracy_smallest.csv").set_index("scene")
    assert smallest.loc["fast", "variant"] == "b5000_i1000"
    index = (tmp_path / "index.md").read_text()
    assert "### Smallest budget within 0.2 dB of the best, per scene" in index
    assert "- Studio needs 500 Gaussians; Fast motion still gains at 5000, its largest budget tried." in index


def test_the_page_repeats_the_search_on_colour_aligned_psnr(tmp_path: Path) -> None:
    """Raw PSNR can flatten on an error no budget removes (the held-out camera's colour) while
    colour-aligned PSNR still gains: planted so, the two sections choose different budgets."""
    from harness.report.results import ReportData
    from harness.report.sections import TablesSection
    from harness.report.speed_accuracy_text import colour_aligned_markdown
    from harness.report.writer import study_page
    from harness.spec.runs import Selection

    df = _frame()
    df["psnr_cc"] = df["psnr"] + df["budget"] / 1000  # every doubling still gains on colour-aligned PSNR
    section = colour_aligned_markdown(df)
    assert section.startswith("### Smallest budget within 0.2 dB of the best, per scene, on colour-aligned PSNR")
    row = next(r for r in section.splitlines() if r.startswith("| Static |"))
    assert "5000 (`b5000_i1000`)" in row  # raw PSNR chose 500
    data = ReportData(_study(), Selection(), [], df, "sqlite:///mlflow.db", "ftgspp/sa3", [], None)
    page = study_page(data, tmp_path, TablesSection([], {}, "", ""), [], [], [])
    assert page.index("per scene\n") < page.index("per scene, on colour-aligned PSNR")
    assert "per scene, on colour-aligned PSNR" not in study_page(
        ReportData(_study(), Selection(), [], _frame(), "sqlite:///mlflow.db", "ftgspp/sa3", [], None),
        tmp_path, TablesSection([], {}, "", ""), [], [], [])


def test_scenes_best_at_their_largest_budget_are_reported_as_not_saturating() -> None:
    psnr = {k: v for k, v in PSNR.items() if k[0] != "static"}
    psnr[("studio", "b5000_i1000")] = [29.0, 29.1]  # now best, at studio's largest budget, as on fast
    df = _frame(psnr)
    chosen = smallest_per_scene(per_scene(df), df)
    assert list(chosen.largest_budget) == [5000.0, 5000.0]
    assert pair_sentences(chosen) == [
        "Neither Studio nor Fast motion saturates within the grid (each is best at its largest budget)."]


# --- two methods on one grid --------------------------------------------------------------

def _two_methods() -> pd.DataFrame:
    """ftgs and ftgspp on two scenes and two cells; ftgspp is 0.5 dB better, 1.2x slower to
    train, renders at 0.8x the FPS and its model is as big; seeds add known noise."""
    rows = []
    for scene in ("static", "studio"):
        for method, shift, slow in (("ftgs", 0.0, 1.0), ("ftgspp", 0.5, 1.2)):
            for budget in (500, 5000):
                for seed in range(3):
                    psnr = 28.0 + shift + budget / 5000 + 0.1 * seed
                    rows.append({
                        "variant": f"{method}_b{budget}_i1000", "scene": scene, "seed": seed,
                        "scene_label": LABELS[scene], "budget": float(budget), "iterations": 1000.0,
                        "status": "FINISHED", "failure": "", "error": "", "run_id": "r", "psnr": psnr,
                        "psnr_cc": psnr + 2.0, "lpips_alex": 0.2 - 0.01 * shift - 0.001 * seed,
                        "train_seconds": slow * budget / 100, "n_gaussians": float(budget),
                        "n_faded": 0.1 * budget, "render_fps_1thread": 1000.0 / budget / slow,
                        "render_fps_all_cores": 1500.0 / budget / slow, "model_bytes": 60.0 * budget})
    return pd.DataFrame(rows)


def test_the_method_is_the_variant_name_before_its_grid_cell() -> None:
    from harness.analysis.speed_accuracy_scenes import method_of

    assert method_of("ftgspp_b5000_i3000") == "ftgspp" and method_of("ftgs_b500k_i30k") == "ftgs"
    assert method_of("b5000_i3000") == "" and method_of("baseline") == ""


def test_each_method_has_its_own_smallest_budget_and_pareto_front() -> None:
    df = _two_methods()
    sa = per_scene(df)
    assert set(sa.method) == {"ftgs", "ftgspp"} and len(sa) == 8
    ftgspp = sa[(sa.scene == "static") & (sa.method == "ftgspp")].set_index("variant")
    assert ftgspp.loc["ftgspp_b5000_i1000", "render_fps_1thread_mean"] == pytest.approx(1000 / 5000 / 1.2)
    assert ftgspp.loc["ftgspp_b5000_i1000", "n_alive"] == pytest.approx(4500)
    assert ftgspp.pareto_time.all()  # within one method: more time, more PSNR
    chosen = smallest_per_scene(sa, df)
    assert list(zip(chosen.scene, chosen.method, chosen.budget)) == [
        ("static", "ftgs", 5000), ("static", "ftgspp", 5000), ("studio", "ftgs", 5000), ("studio", "ftgspp", 5000)]
    assert any(s.startswith("`ftgspp`: ") for s in pair_sentences(chosen))


def test_method_comparison_differences_and_ratios() -> None:
    from harness.analysis.speed_accuracy_scenes import method_comparison

    df = _two_methods()
    cmp = method_comparison(df).set_index(["scene", "budget"])
    r = cmp.loc[("studio", 500.0)]
    assert (r["first"], r["second"]) == ("ftgs", "ftgspp")
    assert r.d_psnr == pytest.approx(0.5) and r.d_lpips_alex == pytest.approx(-0.005)
    a = df[(df.scene == "studio") & (df.variant == "ftgs_b500_i1000")].psnr
    b = df[(df.scene == "studio") & (df.variant == "ftgspp_b500_i1000")].psnr
    ci = stats.ttest_ind(b, a, equal_var=False).confidence_interval(0.95)
    assert (r.d_psnr_low, r.d_psnr_high) == pytest.approx((ci.low, ci.high))
    assert r.r_train_seconds == pytest.approx(1.2) and r.r_render_fps_1thread == pytest.approx(1 / 1.2)
    assert r.r_model_bytes == pytest.approx(1.0) and r.r_n_alive == pytest.approx(1.0)
    from harness.report.speed_accuracy_text import method_markdown

    md = method_markdown(df)
    assert "What `ftgspp` costs and buys against `ftgs`" in md and "| ×1.20 | ×0.83 | ×1.00 | ×1.00 |" in md
    assert method_markdown(df[df.variant.str.startswith("ftgs_")]) == ""  # one method: nothing to compare


def test_pareto_front_respects_each_axis_direction() -> None:
    from harness.report.pareto_plots import front

    cost = np.array([1.0, 2.0, 3.0, 2.5])
    quality = np.array([30.0, 31.0, 30.5, 31.5])
    assert list(front(cost, quality, False, False)) == [True, True, False, True]
    assert list(front(cost, quality, True, False)) == [False, False, True, True]  # more is better (FPS)
    assert list(front(cost, quality, False, True)) == [True, False, False, False]  # lower quality better (LPIPS)


def test_pareto_plot_draws_both_methods_and_says_what_was_not_measured(tmp_path: Path) -> None:
    from harness.report.pareto_plots import pareto_plot

    df = _two_methods().drop(columns=["render_fps_1thread"])
    path = pareto_plot(per_scene(df), "psnr", "toy", tmp_path / "p.png")
    assert path.stat().st_size > 0
