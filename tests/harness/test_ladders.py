"""Stability ladders on hand-built runs whose outcomes and first breaks are known."""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd
import pytest
import yaml

from harness.analysis import ladder_breaks
from harness.report import ladder_figures, sections
from harness.report.results import ReportData
from harness.spec.runs import Selection
from harness.spec.study_files import parse_study
from harness.spec.study_schema import StudyScene

# The base cell is a rung of both ladders; the rest are listed out of order on purpose.
# ftgspp_no_gate is a component ablation run on lr x30 only (judged against ftgspp's base cell);
# gate_only extends no variant's name, so it has no reference.
SCENES = (
    StudyScene("lr30", label="lr x30", rungs=(("lr_scale", 30.0),),
              variants=("baseline", "ftgspp", "ftgspp_no_gate", "gate_only")),
    StudyScene("cams3", label="3 cameras", rungs=(("cameras", 3.0),), variants=("baseline", "ftgspp")),
    StudyScene("base", rungs=(("lr_scale", 1.0), ("cameras", 10.0))),
    StudyScene("lr10", label="lr x10", rungs=(("lr_scale", 10.0),), variants=("baseline", "ftgspp")),
    StudyScene("cams6", label="6 cameras", rungs=(("cameras", 6.0),), variants=("baseline", "ftgspp")),
    StudyScene("lr3", label="lr x3", rungs=(("lr_scale", 3.0),), variants=("baseline", "ftgspp")),
    StudyScene("cams4", label="4 cameras", rungs=(("cameras", 4.0),), variants=("baseline", "ftgspp")),
)
# (variant, scene) -> per seed: (colour-aligned PSNR, held-out gap psnr_cc - psnr) of a
# finished run, or (status, failure)
RUNS = {
    ("baseline", "base"): [(30.0, 1.0), (30.4, 1.0)],  # quality reference 30.2; the cell's gap 1.0
    ("ftgspp", "base"): [(31.0, 1.2), (31.2, 1.0)],  # reference 31.1
    ("baseline", "lr3"): [(30.1, 1.0), (30.1, 1.0)],  # within 0.2 dB of 30.2: ok
    ("ftgspp", "lr3"): [(31.0, 1.1), (30.8, 5.5)],  # gap 5.5 > baseline's 1.0 + 3: colour collapse
    ("baseline", "lr10"): [(25.2, 1.0), (30.1, 1.0)],  # 25.2 < 30.2 - 0.2: quality loss
    ("ftgspp", "lr10"): [(30.5, 1.0), (30.95, 1.0)],  # 30.5 < 30.9: quality loss
    ("baseline", "lr30"): [("FAILED", "diverged"), ("FAILED", "crashed")],
    ("ftgspp", "lr30"): [(30.0, 9.0), (29.5, 1.0)],  # no finished baseline run here: gap not judged
    ("ftgspp_no_gate", "lr30"): [(24.0, 1.0), ("FAILED", "diverged")],  # judged against ftgspp's 31.1
    ("gate_only", "lr30"): [(24.0, 1.0)],  # no reference of its own or by name: not judged
    ("baseline", "cams6"): [(29.0, 1.0), ("KILLED", "interrupted")],  # interrupted: not attempted
    ("ftgspp", "cams6"): [(30.95, 1.0), (31.0, 1.0)],  # less than 0.2 dB below 31.1: ok
    ("baseline", "cams4"): [(28.5, 1.0), (28.1, 1.0)],
    ("ftgspp", "cams4"): [("FAILED", "crashed"), (30.2, 1.0)],
    ("baseline", "cams3"): [(30.05, 1.0), ("MISSING", "")],
    ("ftgspp", "cams3"): [("FAILED", "diverged"), ("FAILED", "input_error")],  # an input error is a crash
}


def _frame(runs: dict[tuple[str, str], list]) -> pd.DataFrame:
    rows = []
    for (v, s), seeds in runs.items():
        for seed, x in enumerate(seeds):
            finished = isinstance(x[0], float)
            status, failure = ("FINISHED", "") if finished else x
            cc, gap = x if finished else (math.nan, math.nan)
            rows.append({"variant": v, "scene": s, "scene_label": s, "seed": seed, "status": status,
                         "failure": failure, "error": "", "psnr_cc": cc, "psnr": cc - gap})
    return pd.DataFrame(rows)


@pytest.fixture(scope="module")
def table() -> pd.DataFrame:
    return ladder_breaks.ladder_table(_frame(RUNS), SCENES).set_index(["ladder", "scene", "variant"])


def test_rungs_run_from_the_shared_base_in_either_direction() -> None:
    order = {lad.name: [r.value for r in lad.rungs] for lad in ladder_breaks.ladders_of(SCENES)}
    assert order == {"lr_scale": [1.0, 3.0, 10.0, 30.0], "cameras": [10.0, 6.0, 4.0, 3.0]}
    assert [lad.descending for lad in ladder_breaks.ladders_of(SCENES)] == [False, True]


def _counts(r: pd.Series) -> tuple[int, ...]:
    return tuple(int(r[f"n_{k}"]) for k in ("ok", *ladder_breaks.KINDS))  # ok, crash, div, colour, quality


def test_each_failure_kind_is_counted_by_its_own_symptom(table: pd.DataFrame) -> None:
    assert _counts(table.loc[("lr_scale", "lr3", "ftgspp")]) == (1, 0, 0, 1, 0)  # the gap, not the PSNR
    assert _counts(table.loc[("lr_scale", "lr10", "baseline")]) == (1, 0, 0, 0, 1)
    assert _counts(table.loc[("lr_scale", "lr30", "baseline")]) == (0, 1, 1, 0, 0)
    assert _counts(table.loc[("cameras", "cams3", "ftgspp")]) == (0, 1, 1, 0, 0)
    assert _counts(table.loc[("cameras", "cams6", "ftgspp")]) == (2, 0, 0, 0, 0)  # under 0.2 dB below: ok
    r = table.loc[("lr_scale", "lr10", "baseline")]
    assert r.reference_psnr == pytest.approx(30.2)
    assert table.loc[("lr_scale", "lr10", "ftgspp")].reference_gap == pytest.approx(1.0)  # the baseline's
    assert r.psnr_cc_mean == pytest.approx((25.2 + 30.1) / 2)
    assert r.psnr_mean == pytest.approx((24.2 + 29.1) / 2)
    assert (r.rate_quality, r.break_rate) == (0.5, 0.0)


def test_colour_collapse_needs_the_baselines_gap_in_the_same_cell(table: pd.DataFrame) -> None:
    r = table.loc[("lr_scale", "lr30", "ftgspp")]  # gap 9.0, but the baseline diverged there
    assert math.isnan(r.reference_gap) and _counts(r) == (0, 0, 0, 0, 2)
    assert math.isnan(table.loc[("lr_scale", "lr3", "baseline")].reference_gap)  # the baseline is the reference


def test_rates_carry_exact_intervals(table: pd.DataFrame) -> None:
    r = table.loc[("lr_scale", "lr30", "baseline")]
    assert r.break_rate == 1.0 and r.break_rate_low == pytest.approx(0.158, abs=1e-3)  # 2 of 2
    assert r.rate_crashed_low == pytest.approx(0.0126, abs=1e-3) and r.rate_crashed_high == pytest.approx(0.987, abs=1e-3)
    ok = table.loc[("cameras", "cams6", "ftgspp")]
    assert ok.rate_quality == 0.0 and ok.rate_quality_high == pytest.approx(0.842, abs=1e-3)  # 0 of 2
    killed = table.loc[("cameras", "cams6", "baseline")]
    assert (killed.n_attempted, killed.n_not_run) == (1, 1)


def test_base_cell_runs_never_lose_quality() -> None:
    runs = {("ftgspp", "base"): [(31.0, 1.0), (23.0, 1.0)], ("ftgspp", "lr3"): [(26.9, 1.0), (26.7, 1.0)]}  # ref 27.0
    t = ladder_breaks.ladder_table(_frame(runs), SCENES).set_index(["ladder", "scene", "variant"])
    for lad in ("lr_scale", "cameras"):
        assert _counts(t.loc[(lad, "base", "ftgspp")]) == (2, 0, 0, 0, 0)
    assert _counts(t.loc[("lr_scale", "lr3", "ftgspp")]) == (1, 0, 0, 0, 1)  # 26.7 < 27.0 - 0.2


def test_first_break_and_first_loss_for_climbing_and_descending_ladders() -> None:
    breaks = ladder_breaks.first_breaks(ladder_breaks.ladder_table(_frame(RUNS), SCENES)).set_index(["ladder", "variant"])
    assert breaks.loc[("lr_scale", "ftgspp")].first_break == 3.0  # the colour collapse
    assert breaks.loc[("lr_scale", "baseline")].first_break == 30.0
    assert math.isnan(breaks.loc[("lr_scale", "baseline")].first_loss)  # 25.2 and 30.1 at x10: not settled
    assert breaks.loc[("cameras", "ftgspp")].text == "cameras 4 (4 cameras)"
    assert breaks.loc[("cameras", "baseline")].text == "none up to cameras 3"
    assert breaks.loc[("cameras", "baseline")].loss_text == "cameras 4 (4 cameras)"  # one run at 6: no interval


def test_changing_rungs_name_both_sides_of_each_change(table: pd.DataFrame) -> None:
    change = ladder_breaks.changing_rungs(table.reset_index())
    base_line = change[(change.ladder == "lr_scale") & (change.variant == "baseline")]
    assert list(base_line.rung) == [3.0, 10.0, 30.0]  # lr3 -> lr10 (quality), lr10 -> lr30 (failures)


def test_component_variant_only_where_it_ran_judged_against_the_method_it_extends(table: pd.DataFrame) -> None:
    comp = table.xs("ftgspp_no_gate", level="variant")
    assert list(comp.index) == [("lr_scale", "lr30")]
    r = comp.iloc[0]
    assert r.role == ladder_breaks.COMPONENT and r.reference_psnr == pytest.approx(31.1)
    assert _counts(r) == (0, 0, 1, 0, 1)
    odd = table.loc[("lr_scale", "lr30", "gate_only")]
    assert math.isnan(odd.reference_psnr) and _counts(odd) == (1, 0, 0, 0, 0)  # 24 dB not judged
    assert table.loc[("lr_scale", "lr30", "ftgspp")].role == ladder_breaks.METHOD


def test_markdown_states_the_rule_the_rates_and_the_breaks() -> None:
    t = ladder_breaks.ladder_table(_frame(RUNS), SCENES)
    md = ladder_figures.ladders_markdown(t, ladder_breaks.first_breaks(t))
    assert ladder_breaks.FAILURE_RULE in md
    assert ("| 30 | lr x30 | `baseline` | 2 | — ± — | — ± — | 1/2 (1–99 %) | 1/2 (1–99 %) | 0/2 (≤ 84 %) |"
            " 0/2 (≤ 84 %) |") in md
    assert "`ftgspp` lr_scale 3 (lr x3)" in md and "`baseline` lr_scale 30 (lr x30)" in md
    assert "| `gate_only` | component | 1 | 24.00 ± — | 23.00 ± — |" in md
    assert "ftgspp_no_gate" not in md.split("### Component variants")[0]  # not a ladder row
    assert "have fewer than 5 runs" in md


def test_write_makes_csv_plot_and_section(tmp_path: Path) -> None:
    md = ladder_figures.write(_frame(RUNS), SCENES, tmp_path, "toy ladders")
    assert (tmp_path / "ladders.png").stat().st_size > 0
    assert len(pd.read_csv(tmp_path / "ladders.csv")) == 2 * 4 * 2 + 2
    assert "(ladders.png)" in md


def test_cell_break_rates_count_a_base_run_once() -> None:
    rates = ladder_breaks.cell_break_rates(_frame(RUNS), SCENES).set_index(["variant", "scene"])
    assert rates.loc[("ftgspp", "lr3")].break_rate == 0.5 and rates.loc[("baseline", "base")].break_rate == 0.0
    assert rates.loc[("baseline", "lr10")].quality_rate == 0.5


def test_studies_without_rungs_have_no_ladders() -> None:
    plain = (StudyScene("easy"), StudyScene("hard"))
    assert not ladder_breaks.has_ladders(plain)
    assert ladder_breaks.ladder_table(_frame(RUNS), plain).empty


def test_report_adds_the_section_only_when_cells_are_rungs(tmp_path: Path) -> None:
    raw = yaml.safe_load((Path(__file__).parent / "studies" / "toy.yaml").read_text())
    scene = raw["profiles"]["quick"]["scenes"][0]
    plain = parse_study(raw, tmp_path / "toy.yaml")
    raw["profiles"]["quick"]["scenes"] = [
        {**scene, "name": "base", "rungs": {"lr_scale": 1}},
        {**scene, "name": "lr10", "rungs": {"lr_scale": 10}},
    ]
    laddered = parse_study(raw, tmp_path / "toy.yaml")
    df = _frame({("baseline", "base"): [(30.0, 1.0), (30.4, 1.0)], ("baseline", "lr10"): [(25.2, 1.0), ("FAILED", "diverged")]})
    for study, out in ((plain, tmp_path / "plain"), (laddered, tmp_path / "laddered")):
        out.mkdir()
        data = ReportData(study, Selection(), [], df, "", "", [], None)
        section = sections.ladders_section(data, out)
        assert (section is not None) == (study is laddered)
        assert (out / "ladders.png").exists() == (study is laddered)
    assert section is not None and section.title == "Stability ladders"
    assert "| 10 | lr10 | `baseline` | 2 | 25.20 ± — | 24.20 ± — | 0/2 (≤ 84 %) | 1/2 (1–99 %) |" in section.md


def test_a_loss_is_settled_only_when_its_welch_interval_clears_the_sesoi(table: pd.DataFrame) -> None:
    from scipy import stats

    r = table.loc[("cameras", "cams4", "baseline")]  # 28.5, 28.1 against the base cell's 30.0, 30.4
    ci = stats.ttest_ind([28.5, 28.1], [30.0, 30.4], equal_var=False).confidence_interval(0.95)
    assert r.loss_diff == pytest.approx(-1.9) and (r.loss_diff_low, r.loss_diff_high) == pytest.approx((ci.low, ci.high))
    assert r.loss_settled == 1.0
    noisy = table.loc[("lr_scale", "lr10", "baseline")]  # one run 5 dB down, one not: counted, not settled
    assert noisy.n_quality == 1 and noisy.loss_settled == 0.0
    assert math.isnan(table.loc[("cameras", "cams6", "baseline")].loss_settled)  # one run: no interval
    assert math.isnan(table.loc[("cameras", "base", "baseline")].loss_settled)  # the base itself
