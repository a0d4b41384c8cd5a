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


def _rows(df: pd.DataFrame, raw: dict = SEQ_STUDY) -> tuple[pd.DataFrame, S.Design]:
    """The study's evaluated rows annotated as the report does (its group's α shared with every
    study file of the project, as ``study decide`` shares it), and the design it used."""
    study = _study(raw)
    frame = V.evaluate(df, study.claims, "seq", Register())
    every = {n: load_study(n) for n in list_studies()}
    return sequential_rows.annotate(frame, study, df, Register()), S.design(study, "quick", Register(), lambda: every)


def test_the_rows_of_a_sequential_design_take_the_replays_verdict() -> None:
    df = _frame({"base": 9, "cc": 9, "gate": 9, "free": 9})
    frame, d = _rows(df)
    replay = {o.claim.spec.id: o for f in S.decide(d, df) for o in f.outcomes}
    assert set(frame.claim[frame.seq_verdict != ""]) == set(replay) == {"cc_mean", "gate_mean", "free_welch"}
    decided = V.decide(frame)
    for cid, o in replay.items():
        row = decided[decided.id == cid].iloc[0]
        want = o.decision.verdict if o.status == Q.DECIDED else V.INCONCLUSIVE
        assert row.verdict == want and math.isnan(row.p_adj)
        assert row.seq_alpha == pytest.approx(d.alpha(str(row.group)))
        assert "run until decided" in row.family and glance.reason(_statement(), row) == row.seq_text
    # a study without a sequential block: no columns, the fixed-n decision as before
    plain = copy.deepcopy(SEQ_STUDY)
    del plain["profiles"]["quick"]["sequential"]
    rows = V.evaluate(df, _study(plain).claims, "seq", Register())
    assert "seq_verdict" not in sequential_rows.annotate(rows, _study(plain), df, Register())


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
