"""Is a report this checkout's? A stale page and index say so first, with the command that
refreshes them and its time; ``make reports``'s planner gives the README's figure; ``study
report`` from the committed runs when the store has none; a report raises no numpy or
statsmodels warning; the index of a fresh store reads right."""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from fakes import MINI_STUDY, fake_generate, fake_train

from ftgspp.errors import InputError
from harness.analysis import verdicts as V
from harness.report.index import StudyClaims, index_markdown
from harness.spec.throughput import QUICK_RUNS_PER_HOUR, estimate

ROOT = Path(__file__).resolve().parents[2]
STUDY = {  # MINI_STUDY's first two claims, its quick profile run 2 at a time
    **MINI_STUDY,
    "claims": MINI_STUDY["claims"][:2],
    "diagnostics": ["lifetime*"],  # a report copies only the diagnostics its study names
    "profiles": {
        "quick": {k: v for k, v in {**MINI_STUDY["profiles"]["quick"], "jobs": 2}.items() if k != "command"},
        "paper": MINI_STUDY["profiles"]["paper"],
    },
}
OTHER = "0ther0ther00"  # a trainer fingerprint no checkout has


def _entry(fingerprint: str) -> StudyClaims:
    return StudyClaims("mini", "q", pd.DataFrame(columns=V.COLUMNS), "mini/index.md", 6, "abc1234", (fingerprint,))


def test_the_index_opens_with_a_stale_note_only_when_its_runs_are_another_trainers() -> None:
    current = index_markdown([_entry("aaaaaaaaaaaa")], [], [], current="aaaaaaaaaaaa")
    lines = current.splitlines()
    assert "Stale" not in current and lines[2].startswith("**Design.**") and lines[4].startswith("Regenerate with")
    page = index_markdown([_entry("aaaaaaaaaaaa")], [], [], current="bbbbbbbbbbbb",
                          todo=(456, estimate(456, 2, "AVX-512").text()))
    note = page.splitlines()[2]
    assert note.startswith("**Stale: these numbers are not this checkout's.**")
    assert "made by trainer `aaaaaaaaaaaa`" in note and "this checkout's trainer is `bbbbbbbbbbbb`" in note
    assert "`make reports`: 456 runs to do, ~1.9 h on this machine" in note and "measured with AVX-512" in note


def test_the_index_of_a_fresh_store_says_no_hypotheses_were_tested() -> None:
    page = index_markdown([], [], ["mini"])
    assert "- **paper** (the paper's method claims): no hypotheses tested yet." in page
    assert "nothing tested" not in page and "Holm over" not in page


def test_the_planner_gives_the_readmes_expected_time(monkeypatch: pytest.MonkeyPatch,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    import harness.cli.reports_plan as plan
    import harness.spec.throughput as throughput
    from harness.spec.runs import Selection, expand
    from harness.spec.study_files import list_studies, load_study

    readme = (ROOT / "README.md").read_text()
    runs, jobs = map(int, re.search(r"\((\d+) quick runs,\s+(\d+) at a time,\s+on 2 cores\)", readme).groups())
    assert runs == sum(len(expand(load_study(s), Selection(profile="quick"))) for s in list_studies())
    rows = {m.group(1): m.group(0) for m in re.finditer(r"^\| (AVX-512|AVX2)\b.*$", readme, re.MULTILINE)}
    assert set(rows) == set(QUICK_RUNS_PER_HOUR)
    for isa, row in rows.items():
        est = estimate(runs, jobs, isa)
        assert f"| about {est.hours:.1f} h |" in row, row
        assert f"{runs} runs × {throughput.MIX:g} at" in row
        assert f"{QUICK_RUNS_PER_HOUR[isa]:.0f} quick runs an hour" in row

    # the planner's own line, as `make reports` runs it (2 at a time is its default too)
    monkeypatch.setattr(throughput, "host_isa", lambda: "AVX-512")
    frame = pd.DataFrame([{"study": "all", "planned": runs, "finished": 0, "to_run": runs, "source": "store"}])
    monkeypatch.setattr(plan, "plan_frame", lambda profile: frame)
    assert plan.main([]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert last.startswith(f"expected: {runs} of {runs} runs to do, ~{estimate(runs, 2, 'AVX-512').hours:.1f} h (")
    hours = f"{estimate(runs, 2, 'AVX-512').hours:.1f} h"
    assert f"about {hours}" in rows["AVX-512"] and f"~{hours}" in last  # the README says what the planner says


def test_a_host_without_a_measured_rate_gets_the_slowest_and_is_told_so() -> None:
    est = estimate(10, 2, "SSE2")
    assert est.runs_per_hour == min(QUICK_RUNS_PER_HOUR.values()) and "none measured with SSE2" in est.text()
    assert estimate(10, 1, "AVX2").hours > estimate(10, 2, "AVX2").hours


def test_variance_and_equivalence_tests_raise_no_numpy_warnings() -> None:
    from harness.analysis import stats
    from harness.analysis.claim_tests import compare_variances

    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        # some resamples repeat one value (SD 0): infinite ratios, and with 3 runs an arm 0/0
        res = compare_variances(np.array([30.0, 30.4, 29.7, 30.2, 30.5]), np.array([30.1, 30.2, 29.9, 30.0, 30.3]), 2.0)
        assert np.isfinite(res.p) and res.ci[0] <= res.effect <= res.ci[1]
        few = compare_variances(np.array([30.0, 30.4, 29.7]), np.array([30.1, 30.2, 29.9]), 2.0)
        assert np.isfinite(few.effect)
        assert stats.tost_paired(np.array([0.25, 0.25, 0.25]), 0.5) == 0.0  # identical differences, inside ±SESOI
        assert stats.tost_paired(np.array([0.75, 0.75, 0.75]), 0.5) == 1.0


@pytest.mark.usefixtures("workdir")
def test_stale_pages_and_reports_from_the_committed_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    import harness.spec.study_files
    from harness.cli.study import main
    from harness.report.index import write_claims_index
    from harness.report.writer import write_report
    from harness.run.runner import run_study
    from harness.spec.runs import Selection
    from harness.tracking.provenance import CHECKOUT_FINGERPRINT, trainer_fingerprint

    studies = tmp_path / "studies"
    studies.mkdir()
    (studies / "mini.yaml").write_text(yaml.safe_dump(STUDY))
    monkeypatch.setattr(harness.spec.study_files, "STUDIES_DIR", studies)
    run_study("mini", Selection(), studies_dir=studies, train_fn=fake_train, generate=fake_generate,
              echo=lambda s: None)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # numpy and statsmodels report theirs as these
        write_report("mini", studies_dir=studies, reports_root=Path("reports"), echo=lambda s: None)
    committed = Path("reports/mini")
    page = (committed / "index.md").read_text()
    assert "Stale" not in page and page.splitlines()[2].startswith("**Question.**")
    assert "Stale" not in write_claims_index(Path("reports"), studies, echo=lambda s: None).read_text()

    # the same runs, read by a checkout with another trainer: both pages say so first
    monkeypatch.setenv(CHECKOUT_FINGERPRINT, OTHER)
    stale = write_report("mini", studies_dir=studies, reports_root=Path("stale"), echo=lambda s: None).read_text()
    note = stale.splitlines()[2]
    assert note.startswith("**Stale: these numbers are not this checkout's.**")
    assert f"made by trainer `{trainer_fingerprint()}`" in note and f"this checkout's trainer is `{OTHER}`" in note
    assert "`study run mini --profile quick --rerun-stale && study report mini`: 6 runs to do, ~" in note
    index = write_claims_index(Path("stale"), studies, echo=lambda s: None).read_text().splitlines()
    assert index[2].startswith("**Stale") and "`make reports`: 6 runs to do" in index[2]
    monkeypatch.delenv(CHECKOUT_FINGERPRINT)

    # a checkout without the runs: `study report mini` reads the committed ones
    Path("mlflow.db").rename("elsewhere.db")
    capsys.readouterr()
    assert main(["report", "mini", "--out", "again"]) == 0
    out = capsys.readouterr().out
    assert "mini: the tracking store has none of its runs; reporting from the committed runs of" in out
    again = Path("again/mini")
    files = sorted(p.relative_to(committed).as_posix() for p in committed.rglob("*") if p.is_file())
    stamped = {"index.md", "table.tex", ".fingerprint"}  # a generation stamp; the harness commit
    assert {"runs.csv", "claims.csv", "table.md"} <= set(files)
    for name in set(files) - stamped:
        assert (again / name).read_bytes() == (committed / name).read_bytes(), name
    diags = [f for f in files if f.startswith("diagnostics/")]
    assert diags
    ours, theirs = (again / "index.md").read_text().splitlines(), page.splitlines()
    assert ours[:-1] == theirs[:-1]  # all but the generation stamp
    assert ours[-1].startswith("_Generated by `study report mini` from the committed runs of ")

    # what the committed report lacks is named, and without its runs.csv nothing is written
    for d in diags:
        (committed / d).unlink()
    for d in sorted((committed / "diagnostics").rglob("*"), reverse=True):
        d.rmdir()
    lines: list[str] = []
    lacking = write_report("mini", studies_dir=studies, reports_root=Path("again2"), echo=lines.append).read_text()
    assert "Not shown: the diagnostics of baseline / easy, cc / easy" in lacking
    assert any("not in the committed report, so not on the page: the diagnostics of" in line for line in lines)
    (committed / "runs.csv").unlink()
    with pytest.raises(InputError, match="no committed runs"):
        write_report("mini", studies_dir=studies, reports_root=Path("again3"), echo=lambda s: None)


def test_runs_of_a_trainer_recorded_to_train_the_same_bits_count_as_current(tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    from types import SimpleNamespace

    import harness.tracking.provenance as prov
    from harness.report import currency
    from harness.run.lease import counts_as_done

    a, b, c, d = "a" * 12, "b" * 12, "c" * 12, "d" * 12
    path = tmp_path / "same_bits.yaml"
    path.write_text(yaml.safe_dump([
        {"trainer": b, "same_bits_as": a, "change": "a refactor", "evidence": "study check x: 3 of 3 identical"},
        {"trainer": c, "same_bits_as": b, "change": "a new method", "evidence": "study check y: 5 of 5 identical"},
    ]))
    monkeypatch.setattr(prov, "SAME_BITS", path)
    assert prov.same_bits(c) == {a, b, c} and prov.same_bits(b) == {a, b}  # never forward in time
    assert prov.same_bits(d) == {d}
    assert currency.stale_note([a, c], c, "make reports", 0, "") == []
    assert currency.stale_note([a, d], c, "make reports", 1, "~1 min")[0].startswith("**Stale")
    df = pd.DataFrame({"status": ["FINISHED"] * 3 + ["FAILED"], "trainer_fingerprint": [a, c, d, c]})
    assert currency.to_do(df, c) == 2 and currency.to_do(df, b) == 3
    page = index_markdown([_entry(a), _entry(c)], [], [], current=c)
    assert "Stale" not in page and "More than one trainer" not in page and "recorded to train the same bits" in page
    assert "More than one trainer" in index_markdown([_entry(a), _entry(d)], [], [], current=c)
    run = lambda fp: SimpleNamespace(status="FINISHED", tags={"trainer_fingerprint": fp}, metrics={})  # noqa: E731
    assert counts_as_done(run(a), c) and not counts_as_done(run(d), c)


def test_every_same_bits_record_names_its_check() -> None:
    from harness.tracking.provenance import same_bits_records

    for rec in same_bits_records():
        assert re.fullmatch(r"[0-9a-f]{12}", str(rec["trainer"])) and re.fullmatch(r"[0-9a-f]{12}", str(rec["same_bits_as"]))
        assert "study check" in rec["evidence"] and rec["change"] and rec["date"]


def test_the_plan_states_each_sequential_studys_rounds_and_worst_case() -> None:
    from harness.analysis import sequential_study as S
    from harness.cli.reports_plan import sequential_lines
    from harness.spec.study_files import list_studies, load_register, load_study

    names = list_studies()
    lines = sequential_lines([*names, "not_a_study"], "quick")
    planned = [n for n in names if load_study(n).profiles["quick"].sequential is not None]
    assert [line.split(":")[0].strip() for line in lines] == planned
    d = S.design(load_study(planned[0]), "quick", load_register(), lambda: {n: load_study(n) for n in names})
    assert f"at most {d.rounds()} rounds" in lines[0] and f"worst case {d.worst_case()} of its runs" in lines[0]
