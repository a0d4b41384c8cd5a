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
# (variant, scene) -> per seed: a PSNR (finished) or (status, failure)
RUNS = {
    ("baseline", "base"): [30.0, 30.4],  # reference 30.2
    ("ftgspp", "base"): [31.0, 31.2],  # reference 31.1
    ("baseline", "lr3"): [29.9, 30.1],
    ("ftgspp", "lr3"): [31.0, 30.8],
    ("baseline", "lr10"): [25.2, 29.8],  # 25.2 is 5 dB below 30.2: collapsed
    ("ftgspp", "lr10"): [30.5, 30.7],
    ("baseline", "lr30"): [("FAILED", "diverged"), ("FAILED", "crashed")],
    ("ftgspp", "lr30"): [30.0, 29.5],
    ("ftgspp_no_gate", "lr30"): [24.0, ("FAILED", "diverged")],  # 7.1 dB below ftgspp's 31.1: collapsed
    ("gate_only", "lr30"): [24.0],  # no reference of its own or by name: not judged
    ("baseline", "cams6"): [29.0, ("KILLED", "interrupted")],  # interrupted: not attempted
    ("ftgspp", "cams6"): [30.9, 30.6],
    ("baseline", "cams4"): [28.5, 28.1],
    ("ftgspp", "cams4"): [("FAILED", "crashed"), 30.2],
    ("baseline", "cams3"): [27.3, ("MISSING", "")],  # 2.9 dB below 30.2: not collapsed
    ("ftgspp", "cams3"): [("FAILED", "diverged"), ("FAILED", "input_error")],
}


def _frame(runs: dict[tuple[str, str], list]) -> pd.DataFrame:
    rows = []
    for (v, s), seeds in runs.items():
        for seed, x in enumerate(seeds):
            status, failure = ("FINISHED", "") if isinstance(x, float) else x
            rows.append({"variant": v, "scene": s, "scene_label": s, "seed": seed, "status": status,
                         "failure": failure, "error": "", "psnr": x if isinstance(x, float) else math.nan})
    return pd.DataFrame(rows)


@pytest.fixture(scope="module")
def table() -> pd.DataFrame:
    return ladder_breaks.ladder_table(_frame(RUNS), SCENES).set_index(["ladder", "scene", "variant"])


def test_rungs_run_from_the_shared_base_in_either_direction() -> None:
    order = {lad.name: [r.value for r in lad.rungs] for lad in ladder_breaks.ladders_of(SCENES)}
    assert order == {"lr_scale": [1.0, 3.0, 10.0, 30.0], "cameras": [10.0, 6.0, 4.0, 3.0]}
    assert [lad.descending for lad in ladder_breaks.ladders_of(SCENES)] == [False, True]


def test_a_planted_collapse_counts_as_collapsed_not_ok(table: pd.DataFrame) -> None:
    r = table.loc[("lr_scale", "lr10", "baseline")]
    assert (r.n_attempted, r.n_ok, r.n_collapsed, r.n_crashed, r.n_diverged) == (2, 1, 1, 0, 0)
    assert r.reference_psnr == pytest.approx(30.2)
    assert r.psnr_mean == pytest.approx((25.2 + 29.8) / 2)
    assert r.psnr_ok_mean == pytest.approx(29.8)
    assert r.failure_rate == pytest.approx(0.5)
    near = table.loc[("cameras", "cams3", "baseline")]  # 2.9 dB below: ok; the missing seed is not attempted
    assert (near.n_attempted, near.n_ok, near.n_collapsed, near.failure_rate) == (1, 1, 0, 0.0)


def test_divergence_and_crash_are_counted_separately(table: pd.DataFrame) -> None:
    r = table.loc[("lr_scale", "lr30", "baseline")]
    assert (r.n_attempted, r.n_crashed, r.n_diverged, r.n_collapsed, r.failure_rate) == (2, 1, 1, 0, 1.0)
    assert math.isnan(r.psnr_mean)
    c = table.loc[("cameras", "cams3", "ftgspp")]  # an input error is a crash
    assert (c.n_crashed, c.n_diverged) == (1, 1)
    killed = table.loc[("cameras", "cams6", "baseline")]
    assert (killed.n_attempted, killed.n_not_run, killed.failure_rate) == (1, 1, 0.0)


def test_base_cell_runs_are_never_collapsed() -> None:
    runs = {("ftgspp", "base"): [31.0, 23.0], ("ftgspp", "lr3"): [26.5, 23.5]}  # reference 27.0
    t = ladder_breaks.ladder_table(_frame(runs), SCENES).set_index(["ladder", "scene", "variant"])
    for lad in ("lr_scale", "cameras"):
        base = t.loc[(lad, "base", "ftgspp")]
        assert (base.n_ok, base.n_collapsed) == (2, 0)
    lr3 = t.loc[("lr_scale", "lr3", "ftgspp")]
    assert (lr3.n_ok, lr3.n_collapsed) == (1, 1)  # 23.5 < 27.0 - 3


def test_first_breaking_rung_for_climbing_and_descending_ladders() -> None:
    breaks = ladder_breaks.first_breaks(ladder_breaks.ladder_table(_frame(RUNS), SCENES)).set_index(["ladder", "variant"])
    assert breaks.loc[("lr_scale", "baseline")].first_break == 10.0  # collapse at 10 before the failures at 30
    assert breaks.loc[("cameras", "ftgspp")].first_break == 4.0  # 10 -> 6 -> 4: the crash at 4 comes first
    assert breaks.loc[("cameras", "ftgspp")].text == "cameras 4 (4 cameras)"
    assert math.isnan(breaks.loc[("lr_scale", "ftgspp")].first_break)
    assert breaks.loc[("lr_scale", "ftgspp")].text == "none up to lr_scale 30"
    assert breaks.loc[("cameras", "baseline")].text == "none up to cameras 3"


def test_first_break_column_agrees_with_first_breaks(table: pd.DataFrame) -> None:
    assert table.loc[("lr_scale", "lr3", "baseline")].first_break == 10.0
    assert math.isnan(table.loc[("cameras", "base", "baseline")].first_break)


def test_component_variant_only_where_it_ran_judged_against_the_method_it_extends(table: pd.DataFrame) -> None:
    comp = table.xs("ftgspp_no_gate", level="variant")
    assert list(comp.index) == [("lr_scale", "lr30")]
    r = comp.iloc[0]
    assert r.role == ladder_breaks.COMPONENT and r.reference_psnr == pytest.approx(31.1)
    assert (r.n_ok, r.n_collapsed, r.n_diverged) == (0, 1, 1)
    odd = table.loc[("lr_scale", "lr30", "gate_only")]
    assert math.isnan(odd.reference_psnr) and (odd.n_ok, odd.n_collapsed) == (1, 0)  # 24 dB not judged
    assert table.loc[("lr_scale", "lr30", "ftgspp")].role == ladder_breaks.METHOD


def test_markdown_states_the_rule_the_cells_and_the_breaks() -> None:
    t = ladder_breaks.ladder_table(_frame(RUNS), SCENES)
    md = ladder_figures.ladders_markdown(t, ladder_breaks.first_breaks(t))
    assert ladder_breaks.COLLAPSE_RULE in md
    assert "| 30 | lr x30 | — ± — (fail 2/2: 1/1/0) | 29.75 ± 0.35 (fail 0/2: 0/0/0) |" in md
    assert "`baseline` lr_scale 10 (lr x10); `ftgspp` none up to lr_scale 30." in md
    assert "| `ftgspp_no_gate` | component | 24.00 ± — | 0 / 2 | 0 | 1 | 1 |" in md
    assert "| `gate_only` | component | 24.00 ± — | 1 / 1 | 0 | 0 | — |" in md
    assert "ftgspp_no_gate" not in md.split("### Component variants")[0]  # not a ladder column


def test_write_makes_csv_plot_and_section(tmp_path: Path) -> None:
    md = ladder_figures.write(_frame(RUNS), SCENES, tmp_path, "toy ladders")
    assert (tmp_path / "ladders.png").stat().st_size > 0
    assert len(pd.read_csv(tmp_path / "ladders.csv")) == 2 * 4 * 2 + 2
    assert "![PSNR and failure rate along each ladder](ladders.png)" in md


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
    df = _frame({("baseline", "base"): [30.0, 30.4], ("baseline", "lr10"): [25.2, ("FAILED", "diverged")]})
    for study, out in ((plain, tmp_path / "plain"), (laddered, tmp_path / "laddered")):
        out.mkdir()
        data = ReportData(study, Selection(), [], df, "", "", [], None)
        section = sections.ladders_section(data, out)
        assert (section is not None) == (study is laddered)
        assert (out / "ladders.png").exists() == (study is laddered)
    assert section is not None and section.title == "Stability ladders"
    assert "| 10 | lr10 | 25.20 ± — (fail 2/2: 0/1/1) |" in section.md
