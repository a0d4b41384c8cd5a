"""A report from a tracking store that holds only some of a plan's runs reads the rest from the
committed report (``report.committed.fill_missing``) when a trainer of the same bits made them in
the store's determinism domain: the runs keep their own commit (registration reads it), the page
says which runs came from where, a run the store holds in any state stays the store's, another
trainer's or another machine's runs stay missing, and a cell read whole from the file shows that
report's diagnostics (kept, not cleared, when the report is written over it)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd
import pytest
import yaml
from fakes import MINI_STUDY, fake_generate, fake_train

QUICK = {**MINI_STUDY["profiles"]["quick"], "seeds": 4}
STUDY = {**MINI_STUDY, "claims": MINI_STUDY["claims"][:2], "diagnostics": ["lifetime*"],
         "profiles": {**MINI_STUDY["profiles"], "quick": QUICK}}
KEYS = ["variant", "scene", "seed"]
OLD = "0ldtrainer00"  # recorded (here, by the monkeypatch) to train the store's bits


@pytest.mark.usefixtures("workdir")
def test_a_partial_store_is_completed_from_the_committed_report(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                mlflow_template: Path) -> None:
    import harness.report.committed as committed_module
    import harness.spec.study_files
    from harness.report import families
    from harness.report.writer import write_report
    from harness.run.runner import run_study
    from harness.spec.runs import Selection

    studies = tmp_path / "studies"
    studies.mkdir()
    (studies / "mini.yaml").write_text(yaml.safe_dump(STUDY))
    monkeypatch.setattr(harness.spec.study_files, "STUDIES_DIR", studies)
    quiet = {"studies_dir": studies, "train_fn": fake_train, "generate": fake_generate, "echo": lambda s: None}
    run_study("mini", Selection(), **quiet)
    write_report("mini", studies_dir=studies, reports_root=Path("reports"), echo=lambda s: None)
    committed = pd.read_csv("reports/mini/runs.csv", dtype={"git_sha": str})
    assert len(committed) == 8 and (committed.status == "FINISHED").all()
    shown = sorted(p.name for p in Path("reports/mini/diagnostics/cc/easy").rglob("*") if p.is_file())
    assert shown  # the committed report shows cc's figures

    # a new store with seeds 0 and 1 of the baseline only; seed 1 fails there
    shutil.copyfile(mlflow_template, "second.db")
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{Path('second.db').resolve()}")
    Path("crash_seed1").write_text("")  # the first run of seed 1 crashes (the fake trainer's hook)
    run_study("mini", Selection(profile="quick", seeds=2, variants=["baseline"]), **quiet)
    # what the committed file says of cc: seed 0 from another machine, seed 1 by an older trainer
    # recorded to train the same bits, seed 3 by a trainer of other bits
    marked = committed.copy()
    cc = marked.variant == "cc"
    marked.loc[cc & (marked.seed == 0), "domain"] = "elsewhere00"
    marked.loc[cc & (marked.seed == 1), "trainer_fingerprint"] = OLD
    marked.loc[cc & (marked.seed == 3), "trainer_fingerprint"] = "0ther0ther00"
    diverged = (marked.variant == "baseline") & (marked.seed == 3)
    marked["failure"] = marked["failure"].astype(object)
    marked.loc[diverged, ["status", "failure"]] = ["FAILED", "diverged"]  # an answer: it is read too
    marked.to_csv("reports/mini/runs.csv", index=False)
    real = committed_module.same_bits
    monkeypatch.setattr(committed_module, "same_bits", lambda f: real(f) | {OLD})
    families.forget()

    lines: list[str] = []
    page = write_report("mini", Selection(profile="quick"), studies_dir=studies, reports_root=Path("again"),
                        echo=lines.append).read_text()
    got = pd.read_csv("again/mini/runs.csv", dtype={"git_sha": str}).set_index(KEYS)
    status = got.status.to_dict()
    assert status[("baseline", "easy", 1)] == "FAILED"  # the store's, though the file holds it finished
    assert status[("cc", "easy", 0)] == "MISSING"  # another determinism domain
    assert status[("cc", "easy", 3)] == "MISSING"  # another trainer's bits
    assert status[("baseline", "easy", 3)] == "FAILED" and got.at[("baseline", "easy", 3), "failure"] == "diverged"
    filled = [("baseline", "easy", 2), ("cc", "easy", 1), ("cc", "easy", 2)]
    assert all(status[k] == "FINISHED" for k in filled) and sum(s == "FINISHED" for s in status.values()) == 4
    mine = marked.set_index(KEYS)
    for k in filled:  # the committed rows as written: metrics, run id, commit, start time, trainer
        for col in ("psnr", "run_id", "git_sha", "start_time", "config_hash", "trainer_fingerprint"):
            assert str(got.at[k, col]) == str(mine.at[k, col]), (k, col)
    assert any(line.startswith("mini: 4 of its 8 planned runs, which the tracking store lacks, read from the"
                               " committed report (reports/mini/runs.csv") for line in lines)
    assert "4 runs of the plan, which the store lacks, are read from the committed report (`reports/mini/runs.csv`)" \
        in page
    # cc's finished runs all come from the file: its diagnostics are the committed report's
    again = sorted(p.name for p in Path("again/mini/diagnostics/cc/easy").rglob("*") if p.is_file())
    assert again == shown and "diagnostics/cc/easy/" in page

    # the index and every page decide on the same completed runs
    frame = families.study_frame("mini", Path("again"), studies_dir=studies, profile="quick")
    assert frame.set_index("claim").n["cc_mean"] == "2 vs 2"  # cc 1, 2 (filled); baseline 0 (store), 2 (filled)

    # written over the committed report itself: the files of the cells read from it stay
    write_report("mini", Selection(profile="quick"), studies_dir=studies, reports_root=Path("reports"),
                 echo=lambda s: None)
    assert sorted(p.name for p in Path("reports/mini/diagnostics/cc/easy").rglob("*") if p.is_file()) == shown

    # the store holding every run: nothing is read from the file
    monkeypatch.delenv("MLFLOW_TRACKING_URI")
    families.forget()
    lines.clear()
    write_report("mini", Selection(profile="quick"), studies_dir=studies, reports_root=Path("third"),
                 echo=lines.append)
    assert not any("read from the committed report" in line for line in lines)
