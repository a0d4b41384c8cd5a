"""A report from a tracking store that holds only some of a plan's runs reads the rest from the
committed report (``report.committed.fill_missing``) when a trainer of the same bits made them:
the runs keep their own commit (registration reads it), the page says which runs came from where,
a run the store holds in any state stays the store's, and another trainer's runs stay missing."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd
import pytest
import yaml
from fakes import MINI_STUDY, fake_generate, fake_train

STUDY = {**MINI_STUDY, "claims": MINI_STUDY["claims"][:2], "diagnostics": ["lifetime*"]}
KEYS = ["variant", "scene", "seed"]


@pytest.mark.usefixtures("workdir")
def test_a_partial_store_is_completed_from_the_committed_report(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                mlflow_template: Path) -> None:
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
    assert len(committed) == 6 and (committed.status == "FINISHED").all()

    # a new store with seed 0 of both arms and seed 1 of one arm, which fails there
    shutil.copyfile(mlflow_template, "second.db")
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{Path('second.db').resolve()}")
    Path("crash_seed1").write_text("")  # the first run of seed 1 crashes (the fake trainer's hook)
    run_study("mini", Selection(profile="quick", seeds=2, variants=["baseline"]), **quiet)
    run_study("mini", Selection(profile="quick", seeds=1, variants=["cc"]), **quiet)
    # the committed file says another trainer made seed 2 of cc: that run stays missing
    marked = committed.copy()
    other = (marked.variant == "cc") & (marked.seed == 2)
    marked.loc[other, "trainer_fingerprint"] = "0ther0ther00"
    marked.to_csv("reports/mini/runs.csv", index=False)
    families.forget()

    lines: list[str] = []
    page = write_report("mini", Selection(profile="quick"), studies_dir=studies, reports_root=Path("again"),
                        echo=lines.append).read_text()
    got = pd.read_csv("again/mini/runs.csv", dtype={"git_sha": str}).set_index(KEYS)
    status = got.status.to_dict()
    assert status[("baseline", "easy", 1)] == "FAILED"  # the store's, though the file holds it finished
    assert status[("cc", "easy", 2)] == "MISSING"  # another trainer's
    filled = [("baseline", "easy", 2), ("cc", "easy", 1)]
    assert all(status[k] == "FINISHED" for k in filled) and sum(s == "FINISHED" for s in status.values()) == 4
    mine = marked.set_index(KEYS)
    for k in filled:  # the committed rows as written: metrics, run id, commit and start time
        for col in ("psnr", "run_id", "git_sha", "start_time", "config_hash"):
            assert str(got.at[k, col]) == str(mine.at[k, col]), (k, col)
    assert any(line.startswith("mini: 2 of its 6 planned runs, which the tracking store lacks, read from the"
                               " committed report (reports/mini/runs.csv") for line in lines)
    assert "2 runs of the plan, which the store lacks, are read from the committed report (`reports/mini/runs.csv`)" \
        in page

    # the index and every page decide on the same completed runs
    frame = families.study_frame("mini", Path("again"), studies_dir=studies, profile="quick")
    row = frame.set_index("claim").loc["cc_mean"]
    assert row.n == "2 vs 2"  # seed 0 from the store and one filled run an arm (a FAILED and a missing one out)

    # the store holding every run: nothing is read from the file
    monkeypatch.delenv("MLFLOW_TRACKING_URI")
    families.forget()
    lines.clear()
    write_report("mini", Selection(profile="quick"), studies_dir=studies, reports_root=Path("third"),
                 echo=lines.append)
    assert not any("read from the committed report" in line for line in lines)
