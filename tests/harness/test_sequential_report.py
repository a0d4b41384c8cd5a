"""The report decides a study's rows run until decided by the sequential replay, not by its
fixed-n Holm (issue 57; ``report.sequential_rows``): those rows take ``study decide``'s verdict,
stay out of their group's Holm, and the group's other rows are decided at α less the sequential
share, so the two parts together never spend more than α."""

from __future__ import annotations

import copy
import math

import numpy as np
import pandas as pd
import pytest
import yaml
from test_decide import SEQ_STUDY, _frame, _study

from harness.analysis import sequential as Q, sequential_study as S, stats, verdicts as V
from harness.report import glance, sequential_rows
from harness.spec.paper_register import Register
from harness.spec.study_files import list_studies, load_study
from harness.spec.study_schema import ClaimSpec


def _rows(df: pd.DataFrame, raw: dict = SEQ_STUDY) -> tuple[pd.DataFrame, S.Design | None]:
    """The study's evaluated rows annotated as the report does (``report.families``: its group's α
    shared with every study file of the project, as ``study decide`` shares it), and the design."""
    study = _study(raw)
    d = sequential_rows.design_of(study, Register())
    frame = V.evaluate(df, study.claims, "seq", Register(), sequential_rows.claim_ids(d))
    return sequential_rows.annotate(frame, d, df), d


def test_the_rows_of_a_sequential_design_take_the_replays_verdict() -> None:
    df = _frame({"base": 9, "cc": 9, "gate": 9, "free": 9})
    frame, d = _rows(df)
    every = {n: load_study(n) for n in list_studies()}
    assert d.shares == S.design(_study(), "quick", Register(), lambda: every).shares  # study decide's shares
    replay = {o.claim.spec.id: o for f in S.decide(d, df) for o in f.outcomes}
    assert set(frame.claim[frame.seq_verdict != ""]) == set(replay) == {"cc_mean", "gate_mean", "free_welch"}
    decided = V.decide(frame)
    for cid, o in replay.items():
        row = decided[decided.id == cid].iloc[0]
        want = o.decision.verdict if o.status == Q.DECIDED else V.INCONCLUSIVE
        assert row.verdict == want and math.isnan(row.p_adj)
        assert row.seq_alpha == pytest.approx(d.alpha(str(row.group)))
        assert "run until decided" in row.family and glance.reason(_statement(), row) == row.seq_text
        # its effect and interval are those of the look that decided it (or its last), not of every run
        n = o.decision.n
        a = o.runs.a[:n]
        effect = a.mean() if o.runs.b is None else a.mean() - o.runs.b[:n].mean()
        assert row.effect == pytest.approx(effect) and row.n.startswith(f"{n} ") and row.ci_adj_level == 0.95
    # a study without a sequential block: no design, no columns, the fixed-n decision as before
    plain = copy.deepcopy(SEQ_STUDY)
    del plain["profiles"]["quick"]["sequential"]
    assert sequential_rows.design_of(_study(plain), Register()) is None
    rows = V.evaluate(df, _study(plain).claims, "seq", Register())
    assert "seq_verdict" not in sequential_rows.annotate(rows, None, df)


def test_a_design_the_study_cannot_run_is_an_error_not_a_silent_fixed_n() -> None:
    from test_decide import _instances_study

    with pytest.raises(S.DesignError, match="fresh instances"):
        sequential_rows.design_of(_study(_instances_study(6)), Register())


def test_on_instances_the_report_reads_the_fresh_ones_and_never_splits_a_sequential_claim() -> None:
    from test_decide import _instance_frame, _instances_study

    raw = _instances_study(10)
    df = _instance_frame(5)
    frame, d = _rows(df, raw)
    (row,) = [r for _, r in V.decide(frame).iterrows() if r.id == "cc_mean"]
    calm = df.assign(psnr=df.psnr.where(df.instance > 0, 30.0))  # the pilot's +9 dB changes nothing
    (again,) = [r for _, r in V.decide(_rows(calm, raw)[0]).iterrows() if r.id == "cc_mean"]
    assert (row.verdict, row.effect, row.seq_text) == (again.verdict, again.effect, again.seq_text)
    assert row.n == "5 paired instances"
    # a claim over two scenes whose scenes disagree is split when fixed-n, never when run until decided
    two = copy.deepcopy(SEQ_STUDY)
    runs = _frame({"base": 9, "cc": 9, "gate": 9, "free": 9})
    runs.loc[(runs.variant == "gate") & (runs.scene == "drift"), "psnr"] -= 6.0
    runs.loc[(runs.variant == "gate") & (runs.scene == "studio"), "psnr"] += 6.0
    assert len(V.evaluate(runs, _study(two).claims).query("claim == 'gate_mean'")) == 2  # split by scene
    frame, _ = _rows(runs, two)
    assert list(frame.query("claim == 'gate_mean'").id) == ["gate_mean"]


def _statement():
    class S_:  # the few fields glance.reason reads
        not_tested = ""
        decided_by = ""
    return S_()


def test_the_other_rows_of_the_group_are_decided_at_alpha_less_the_sequential_share() -> None:
    """Two fixed-n rows of group ``paper`` beside one sequential row holding α/3: Holm at 2α/3."""
    claim = ClaimSpec(id="c", statement="s", metric="psnr", test="mean", expect="higher", a="x", b="y",
                      scenes=("studio",), sesoi=0.2)
    base = V._row(claim, "", "", "", None) | {
        "effect": 0.5, "ci_low": 0.1, "ci_high": 0.9, "p_tost": math.nan, "verdict": V.INCONCLUSIVE,
        "registered_before_runs": "yes", "n": "10 pairs", "power_test": "t_paired", "power_param": 1.0}
    rows = [dict(base, id="a", claim="a", p=0.012), dict(base, id="b", claim="b", p=0.4),
            dict(base, id="s", claim="s", p=0.9)]
    frame = pd.DataFrame(rows)
    for col, value in zip(sequential_rows.COLUMNS, ("", math.nan, "", math.nan)):
        frame[col] = value
    plain = V.decide(frame.copy())
    assert plain.set_index("id").verdict["a"] == V.REPRODUCED  # Holm over 3 difference hypotheses: 0.036 < 0.05
    frame.loc[frame.id == "s", ["seq_verdict", "seq_alpha", "seq_text"]] = [V.INCONCLUSIVE, stats.ALPHA / 3, "t"]
    split = V.decide(frame).set_index("id")
    assert split.p_adj["a"] == pytest.approx(0.024) and split.verdict["a"] == V.REPRODUCED  # Holm over 2: < 2α/3
    frame.loc[frame.id == "a", "p"] = 0.02  # Holm over a and b: adjusted 0.04, under α but over 2α/3
    split = V.decide(frame).set_index("id")
    assert split.p_adj["a"] == pytest.approx(0.04) and split.verdict["a"] == V.INCONCLUSIVE
    assert split.verdict["s"] == V.INCONCLUSIVE and np.isnan(split.p_adj["s"])
    assert "at α 0.0333" in split.family["a"] and split.alpha["a"] == pytest.approx(stats.ALPHA * 2 / 3)
    # two studies' sequential claims, each study's holding α/3 (equal shares): both are left out of α
    two = frame.assign(study="x")
    both = pd.concat([two, two[two.id == "s"].assign(id="s2", claim="s2", study="y")], ignore_index=True)
    assert V.decide(both).set_index("id").alpha["a"] == pytest.approx(stats.ALPHA / 3)


def test_the_index_names_the_design_once_from_the_study_files(tmp_path) -> None:
    from harness.report.design_note import design_paragraph

    (para, blank) = design_paragraph()
    assert para.startswith("**Design.**") and blank == ""
    # the counts come from the study files: each study drawing instances, and each plan's looks
    drawn = [n for n in list_studies() if any(s.instance for s in load_study(n).profiles["quick"].scenes)]
    planned = [n for n in list_studies() if load_study(n).profiles["quick"].sequential is not None]
    assert f"{len(drawn)} studies draw" in para and f"mean claims of {len(planned)} studies run until decided" in para
    assert all(f"`{n}`" in para for n in drawn + planned) and "pilot" in para
    # a folder whose studies draw no instances and plan nothing: no paragraph
    raw = copy.deepcopy(SEQ_STUDY)
    del raw["profiles"]["quick"]["sequential"]
    (tmp_path / "seq.yaml").write_text(yaml.safe_dump(raw))
    assert design_paragraph(tmp_path) == []


def test_an_undecided_fixed_n_row_says_the_alpha_it_was_tested_at() -> None:
    from harness.report.glance import reason

    row = pd.Series({"verdict": V.INCONCLUSIVE, "p_adj": 0.04, "p_tost_adj": math.nan, "alpha": 0.024,
                     "interval_note": "", "counted": True})
    assert "at the α 0.024 the family's rows run until decided leave (Holm p = 0.04)" in reason(_statement(), row)
    assert "at the family's α (Holm" in reason(_statement(), row.copy().replace({0.024: stats.ALPHA}))


def test_the_families_line_names_the_fixed_n_holm_and_the_share_the_sequential_rows_hold() -> None:
    from harness.report.design_note import family_text

    df = _frame({"base": 9, "cc": 9, "gate": 9, "free": 9})
    frame, d = _rows(df)
    decided = V.decide(frame.assign(study="seq"))
    paper = decided[(decided.group == "paper") & decided.counted.astype(bool)]
    text = family_text(paper)
    assert f"2 rows of 1 study run until decided, holding α {d.alpha('paper'):.3g}" in text
    assert family_text(paper.iloc[0:0]) == ""


def test_a_study_page_names_each_family_once_with_the_alpha_its_sequential_rows_hold() -> None:
    from harness.report.claims_table import families_text

    frame, d = _rows(_frame({"base": 9, "cc": 9, "gate": 9, "free": 9}))
    decided = V.decide(frame.assign(study="seq")).drop(columns="study")
    lines = families_text(decided)
    groups = sorted({str(g) for g, f in zip(decided.group, decided.family) if f})
    assert len(lines) == len(groups) and all(line.startswith(f"{g} ") or line.startswith(f"{g}:")
                                             for line, g in zip(lines, groups))
    (paper,) = [line for line in lines if line.startswith("paper")]
    assert paper.endswith(f"this study's 2 rows run until decided at α {d.alpha('paper'):.3g}")


def test_an_undecided_row_states_the_runs_and_cpu_hours_a_fixed_design_would_need() -> None:
    """Issue 57: a row still inconclusive says what deciding it would cost, on this study's runs."""
    # a sequential row stopped at its cap: its instances and their CPU hours at the study's run_seconds
    df = _frame({"base": 9, "cc": 9, "gate": 9, "free": 9})  # α shares this small leave every claim at its cap
    frame, d = _rows(df)
    capped = [o for f in S.decide(d, df) for o in f.outcomes if o.status == Q.AT_CAP]
    assert capped and d.profile.run_seconds > 0
    for o in capped:
        text = frame.set_index("id").seq_text[o.claim.spec.id]
        n = int(o.decision.runs_needed)
        assert f"needs about {n} {o.claim.unit}, {d.hours(n * o.claim.plan.arms):.3g} CPU h at" in text
    # a fixed-n row: the runs (or instances) per arm and their hours at the run_seconds given
    row = pd.Series({"verdict": V.INCONCLUSIVE, "p_adj": 0.4, "p_tost_adj": math.nan, "alpha": 0.024,
                     "interval_note": "", "counted": True, "n_needed": 30.0, "family_size": 3.0,
                     "n": "10 paired instances"})
    why = glance.reason(_statement(), row, run_seconds=40.0)
    assert "≈30 instances/arm for 80% power at the SESOI (0.024/3" in why and "0.333 CPU h an arm at 40 s a run" in why
    assert "CPU h" not in glance.reason(_statement(), row)  # no run_seconds stated: no hours made up


def test_the_cpu_hours_of_an_undecided_row_come_from_the_study_folder_the_index_reads(tmp_path) -> None:
    """A study in another folder than studies/ states its own seconds a run (it was ignored before)."""
    import yaml

    from tests.harness.fakes import MINI_STUDY

    (tmp_path / "mini.yaml").write_text(yaml.safe_dump(MINI_STUDY))
    assert glance._run_seconds("mini", tmp_path) == 5.0
    assert math.isnan(glance._run_seconds("mini", tmp_path / "elsewhere"))  # no such study there: no figure
