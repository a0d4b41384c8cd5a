"""The brief's three answers, one sentence each, from report tables whose numbers are planted."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from harness.report.answers import answers_markdown, size_sentence, speed_sentence, stability_sentence


def _write(root: Path, rel: str, rows: list[dict]) -> None:
    (root / rel).parent.mkdir(parents=True, exist_ok=True)
    pd.DataFrame(rows).to_csv(root / rel, index=False)


def test_nothing_to_say_without_tables(tmp_path: Path) -> None:
    assert answers_markdown(tmp_path) == []


def test_speed_uses_the_reference_cell_and_spans_the_scenes(tmp_path: Path) -> None:
    base = {"first": "ftgs", "second": "ftgspp", "iterations": 3000.0, "r_model_bytes": 1.0}
    _write(tmp_path, "speed_accuracy/method_comparison.csv", [
        {**base, "scene_label": "a", "budget": 5000.0, "d_psnr_cc": 0.3, "d_psnr": 0.1, "r_train_seconds": 1.1,
         "r_render_fps_1thread": 0.9, "d_psnr_cc_low": 0.1, "d_psnr_cc_high": 0.5},
        {**base, "scene_label": "b", "budget": 5000.0, "d_psnr_cc": -0.2, "d_psnr": 0.4, "r_train_seconds": 1.3,
         "r_render_fps_1thread": 0.8, "d_psnr_cc_low": -0.9, "d_psnr_cc_high": 0.5},
        {**base, "scene_label": "a", "budget": 500.0, "d_psnr_cc": 9.0, "d_psnr": 9.0, "r_train_seconds": 9.0,
         "r_render_fps_1thread": 9.0}])
    s = speed_sentence(tmp_path)
    assert "at 5,000 Gaussians and 3,000 iterations, `ftgspp` against `ftgs` over 2 scenes" in s
    assert "colour-aligned PSNR -0.20 to +0.30 dB (1 of 2 scenes' 95% intervals exclude 0)" in s
    assert "training time ×1.10 to 1.30" in s
    assert "render FPS at one thread ×0.80 to 0.90" in s and "model size ×1.00" in s and "9.0" not in s


def test_size_names_unsaturated_scenes_and_the_known_answer(tmp_path: Path) -> None:
    row = {"method": "ftgs", "iterations": 3000.0, "largest_budget": 20000.0}
    _write(tmp_path, "speed_accuracy/speed_accuracy_smallest.csv", [
        {**row, "scene_label": "static", "budget": 1500.0, "variant": "ftgs_b1500", "best_variant": "ftgs_b5000",
         "gap_ci_includes_tol": False},
        {**row, "scene_label": "fast", "budget": 20000.0, "variant": "ftgs_b20000", "best_variant": "ftgs_b20000",
         "gap_ci_includes_tol": None},
        {**row, "scene_label": "plain", "budget": 5000.0, "variant": "ftgs_b5000", "best_variant": "ftgs_b5000",
         "gap_ci_includes_tol": None}])
    _write(tmp_path, "budget/budget_known_size/budget.csv", [
        {"budget": b, "chosen": b == 600, "saturated": True, "true_size": 500.0} for b in (250, 500, 600, 1000)])
    s = size_sentence(tmp_path)
    assert ("`ftgs`: static 1,500, fast ≥ 20,000 (no saturation), plain 5,000 (its best: more Gaussians score"
            " lower).") in s and "best raw PSNR" in s  # no colour-aligned table here
    assert "the budget finder answers 600 Gaussians, 1.20× the K = 500 that drew it" in s


def test_stability_names_first_breaks_and_quality_losses(tmp_path: Path) -> None:
    rows = []
    for v, brk in (("baseline", 10.0), ("ftgspp", float("nan"))):
        for rung, broken in ((1.0, 0), (3.0, 0), (10.0, 3 if v == "baseline" else 0)):
            rows.append({"ladder": "lr_scale", "rung": rung, "variant": v, "role": "method", "n_broken": broken,
                         "n_attempted": 3, "first_break": brk, "first_loss": 3.0})
        rows.append({"ladder": "cameras", "rung": 10.0, "variant": v, "role": "method", "n_broken": 0,
                     "n_attempted": 3, "first_break": float("nan"), "first_loss": float("nan")})
    _write(tmp_path, "stability/ladders.csv", rows)
    s = stability_sentence(tmp_path)
    assert "`baseline` breaks first at lr_scale 10 (3/3) and has a settled quality loss on 1 of 2 ladders" in s
    assert "`ftgspp` breaks first at no rung" in s


def test_an_unsaturated_known_size_search_says_so(tmp_path: Path) -> None:
    _write(tmp_path, "budget/budget_known_size/budget.csv", [
        {"budget": b, "chosen": b == 16000, "saturated": False, "true_size": 500.0} for b in (500, 16000)])
    assert size_sentence(tmp_path) == ("On the scene of known size the budget finder answers ≥ 16,000 Gaussians"
                                       " (not saturated at the cap), 32.00× the K = 500 that drew it.")


def test_preset_budget_searches_join_the_size_sentence(tmp_path: Path) -> None:
    _write(tmp_path, "budget/budget_plain/budget.csv", [
        {"budget": b, "chosen": b == 7500, "saturated": True, "settled": False, "true_size": float("nan")}
        for b in (5000, 7500, 10000)])
    _write(tmp_path, "budget/budget_static/budget.csv", [
        {"budget": b, "chosen": b == 40000, "saturated": False, "true_size": float("nan")} for b in (5000, 40000)])
    s = size_sentence(tmp_path)
    assert s.endswith("then the smallest budget whose gap to the best is settled below it): plain 7,500 Gaussians"
                      " (not settled within the SESOI), static ≥ 40,000 Gaussians (not saturated at the cap).")


def test_the_size_answer_gives_drawn_gaussians_bytes_the_gap_and_the_control(tmp_path: Path) -> None:
    """Issue 56: the answer names the Gaussians the chosen models draw, their bytes and the gap's
    interval; the noisy known-size scene's page (a PSNR ceiling) is preferred to the noise-free one's,
    and its control (trained from the true Gaussians at K) stands beside it; unsettled at the cap,
    the runs a budget would need."""
    page = {"true_size": 500.0, "saturated": True, "settled": True, "control_mean": 41.234}
    _write(tmp_path, "budget/budget_known_size_noise2/budget.csv", [
        {**page, "budget": 1000, "chosen": True, "best": False, "n_alive": 912.0, "model_bytes": 61_000.0,
         "gap_mean": 0.05, "gap_low": -0.04, "gap_high": 0.14},
        {**page, "budget": 2000, "chosen": False, "best": True, "n_alive": 1500.0, "model_bytes": 122_000.0,
         "gap_mean": 0.0, "gap_low": 0.0, "gap_high": 0.0}])
    _write(tmp_path, "budget/budget_known_size/budget.csv", [
        {"budget": 16000, "chosen": True, "saturated": False, "true_size": 500.0}])
    _write(tmp_path, "budget/budget_static/budget.csv", [
        {"budget": b, "chosen": b == 40000, "best": True, "saturated": False, "runs_needed": 14.0,
         "n_alive": 21000.0, "true_size": float("nan")} for b in (20000, 40000)])
    s = size_sentence(tmp_path)
    assert ("the budget finder answers 1,000 Gaussians (912 drawn; 0.06 MB; gap to the best +0.05 [-0.04, +0.14] dB),"
            " 2.00× the K = 500 that drew it; started from the true Gaussians at K: 41.23 dB.") in s
    assert "16,000" not in s  # the noise-free page gives way to the noisy one
    assert "static ≥ 40,000 Gaussians (not saturated at the cap; 14 runs a budget would settle it; 21,000 drawn)" in s


def test_pruning_pages_join_the_size_sentence_with_their_smallest_settled_fraction(tmp_path: Path) -> None:
    def page(name: str, settled: list[bool]) -> None:
        (tmp_path / "pruning" / name).mkdir(parents=True)
        rows = [{"keep": 1.0, "n_gaussians": 20000, "psnr": 32.6, "loss": 0.0, "n": 3, "settled": None}]
        rows += [{"keep": k, "n_gaussians": 20000 * k, "psnr": 32.5, "loss": 0.1, "n": 3, "settled": s}
                 for k, s in zip((0.5, 0.25, 0.1), settled)]
        pd.DataFrame(rows).assign(sesoi=0.2).to_csv(tmp_path / "pruning" / name / "settled.csv", index=False)

    page("a", [True, True, False])
    page("b", [False, False, False])
    text = size_sentence(tmp_path)
    assert "a (20,000 Gaussians, 32.60 dB): 5,000 kept (0.25) settled within 0.2 dB" in text
    assert "b (20,000 Gaussians, 32.60 dB): no kept fraction settled within 0.2 dB with 3 seeds" in text


def _search_page(root: Path, scene: str, psnr: list[float], chosen: int, settled: bool) -> None:
    budgets = [500 * 2**i for i in range(len(psnr))]
    _write(root, f"budget/budget_{scene}/budget.csv", [
        {"budget": b, "n": 3, "psnr_mean": p, "chosen": i == chosen, "best": p == max(psnr), "saturated": settled,
         "settled": settled, "sesoi": 0.2, "runs_needed": 40.0} for i, (b, p) in enumerate(zip(budgets, psnr))])


def _pruning_page(root: Path, name: str, kept: list[tuple[int, float, bool]]) -> None:
    rows = [{"keep": 1.0, "n_gaussians": 8000, "psnr": 30.0, "loss": 0.0, "n": 3, "settled": None}]
    rows += [{"keep": n / 8000, "n_gaussians": n, "psnr": p, "loss": 0.1, "loss_low": -0.1, "loss_high": 0.15,
              "n": 3, "settled": s} for n, p, s in kept]
    (root / "pruning" / name).mkdir(parents=True)
    pd.DataFrame(rows).assign(sesoi=0.2).to_csv(root / "pruning" / name / "settled.csv", index=False)


def test_the_search_and_pruning_are_compared_per_scene_and_the_smaller_settled_answer_wins(tmp_path: Path) -> None:
    # scene a: the search settles at 2,000 (30.0 dB best at 4,000); pruning keeps 1,000 within 0.2 dB, settled
    _search_page(tmp_path, "a", [27.0, 29.0, 29.9, 30.0], chosen=2, settled=True)
    _pruning_page(tmp_path, "sa_ftgs_b8000_i3000_a", [(4000, 30.1, True), (1000, 29.85, True), (500, 28.0, True)])
    # scene b: nothing settles; pruning's 2,000 is within 0.2 dB of the search's best in the mean
    _search_page(tmp_path, "b", [27.0, 29.0, 29.9, 30.0], chosen=3, settled=False)
    _pruning_page(tmp_path, "sa_ftgs_b8000_i3000_b", [(2000, 29.9, False)])
    # another method's pruning answers another question: left out; so is a scene with no search page
    _pruning_page(tmp_path, "sa_ftgspp_b8000_i3000_a", [(100, 31.0, True)])
    _pruning_page(tmp_path, "sa_ftgs_b8000_i3000_c", [(100, 31.0, True)])
    text = size_sentence(tmp_path).split("Budget search against pruning, FreeTimeGS, per scene: ")[1]
    a, b = text.rstrip(".").split("; b: ")
    assert a.startswith("a: the search's best 30.00 dB at 4,000, its answer 2,000; pruning 8,000 → 1,000 keeps 29.85")
    assert a.endswith("the answer, 1,000 Gaussians, comes from pruning")
    assert b.startswith("the search's best 30.00 dB at 4,000, its answer ≥ 4,000 (not settled);"
                        " pruning 8,000 → 2,000")
    assert "(not settled against the unpruned model with 3 seeds: loss [-0.10, +0.15] dB)" in b
    assert b.endswith("neither settles, pruning gives the smaller model at the same mean")
    assert "c:" not in text and "100" not in text


def test_an_unsaturated_grid_scene_says_the_runs_that_would_settle_its_last_doubling(tmp_path: Path) -> None:
    """The runs per budget come from the grid's last doubling of that scene, method and iteration
    count only (10,000 against 20,000 here), at the two budgets' pooled SD, by the finder's rule."""
    import numpy as np

    from harness.analysis.budget_search import runs_needed

    row = {"scene": "s", "method": "ftgs", "iterations": 3000.0, "largest_budget": 20000.0, "scene_label": "s"}
    _write(tmp_path, "speed_accuracy/speed_accuracy_smallest_psnr_cc.csv", [
        {**row, "budget": 20000.0, "variant": "ftgs_b20000_i3000", "best_variant": "ftgs_b20000_i3000"}])
    x, y = [35.0, 35.4, 35.2], [35.3, 35.9, 35.6]  # SDs 0.2 and 0.3
    runs = [{"variant": f"ftgs_b{b}_i3000", "scene": "s", "budget": b, "iterations": 3000.0, "status": "FINISHED",
             "psnr_cc": v, "psnr": 0.0} for b, vals in ((10000, x), (20000, y)) for v in vals]
    runs += [{"variant": "ftgs_b5000_i3000", "scene": "s", "budget": 5000, "iterations": 3000.0,
              "status": "FINISHED", "psnr_cc": v, "psnr": 0.0} for v in (20.0, 30.0, 40.0)]  # not the last doubling
    runs += [{"variant": "ftgspp_b10000_i3000", "scene": "s", "budget": 10000, "iterations": 3000.0,  # another method
              "status": "FINISHED", "psnr_cc": v, "psnr": 0.0} for v in (20.0, 30.0, 40.0)]
    runs += [{"variant": "ftgs_b20000_i3000", "scene": "s", "budget": 20000, "iterations": 3000.0,  # a failed run
              "status": "FAILED", "psnr_cc": 10.0, "psnr": 0.0}]
    _write(tmp_path, "speed_accuracy/runs.csv", runs)
    sd = float(np.sqrt((np.var(x, ddof=1) + np.var(y, ddof=1)) / 2))  # equal n: the pooled SD by hand
    need = runs_needed(0.2, sd)
    assert 2 < need < 100
    said = f"s ≥ 20,000 (no saturation; {need:,.0f} runs a budget would settle its last doubling)"
    assert said in size_sentence(tmp_path)


def test_pruning_answers_with_its_fewest_settled_model_when_a_smaller_close_one_is_not(tmp_path: Path) -> None:
    _search_page(tmp_path, "d", [27.0, 29.0, 29.9, 30.0], chosen=3, settled=False)
    _pruning_page(tmp_path, "sa_ftgs_b8000_i3000_d", [(2000, 29.95, True), (1000, 29.9, False)])
    text = size_sentence(tmp_path).split("Budget search against pruning, FreeTimeGS, per scene: ")[1]
    assert "pruning 8,000 → 1,000 keeps 29.90 dB (not settled" in text
    assert text.endswith("the answer, 2,000 Gaussians, comes from pruning.")
