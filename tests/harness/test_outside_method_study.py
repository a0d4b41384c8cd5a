"""A method written outside the ``ftgspp`` package (``tests/methods/toy_static.py``) runs as a
study end to end with the real trainer: a study file whose variants are ``model.method=module:Class``
plus overrides, ``study run`` at smoke scale and ``study report``, as docs/methods.md describes."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

TOY = "tests.methods.toy_static:StaticGaussians"
STUDY = f"""
name: toy_method
question: Does a method from outside the package run as a study, with and without colour correction?
baseline: toy
variants:
  toy: [model.name=toy, model.method={TOY}, model.sh_degree=0]
  toy_cc: [model.name=toy, model.method={TOY}, model.sh_degree=0, model.color_correction=true]
metrics: [psnr, psnr_cc, n_gaussians, "lifetime_*"]
table:
  layout: variants_x_scenes
  metrics: [psnr, psnr_cc]
profiles:
  quick:
    seeds: 2
    overrides: [profile=quick]
    scenes:
      - {{name: studio, synth: {{preset: studio, seed: 0}}}}
    command: study run toy_method
  paper:
    seeds: 2
    overrides: [profile=paper]
    scenes: dynerf
    command: study run toy_method --profile paper
"""


@pytest.mark.slow
def test_a_smoke_study_of_the_outside_method_runs_end_to_end(workdir: Path, monkeypatch: pytest.MonkeyPatch,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    import harness.spec.study_files
    from harness.cli.study import main

    studies = workdir / "studies"
    studies.mkdir()
    (studies / "toy_method.yaml").write_text(STUDY)
    shutil.copy(harness.spec.study_files.STUDIES_DIR / "_scene_sets.yaml", studies)  # the paper profile's scene sets
    monkeypatch.setattr(harness.spec.study_files, "STUDIES_DIR", studies)
    assert main(["run", "toy_method", "--profile", "smoke"]) == 0
    out = capsys.readouterr().out
    assert "2 finished" in out and "0 failed" in out, out[-2000:]
    assert main(["report", "toy_method"]) == 0
    table = (Path("outputs/reports/toy_method") / "table.md").read_text()
    assert "| toy |" in table and "| toy_cc |" in table


@pytest.mark.slow
def test_a_study_file_outside_the_clone_named_by_its_path_with_only_the_profile_it_uses(
        workdir: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 55: `study run path/to/mine.yaml` (no file inside the clone's studies/), a study with a
    quick profile only (no paper profile), and a report whose commands reproduce it: the study's
    path, and the PYTHONPATH the outside method needs."""
    import pandas as pd

    import harness.spec.study_files as study_files
    from harness.cli.study import main

    monkeypatch.setattr(study_files, "STUDIES_DIR", study_files.STUDIES_DIR)  # restored after the test
    monkeypatch.setattr(study_files, "NAMED_FILE", None)
    mine = workdir / "elsewhere" / "toy_method.yaml"
    mine.parent.mkdir()
    mine.write_text(STUDY[: STUDY.index("  paper:")])  # the quick profile only
    assert main(["run", str(mine), "--profile", "smoke", "--variants", "toy"]) == 0
    assert "1 finished" in capsys.readouterr().out
    assert main(["report", str(mine), "--profile", "smoke"]) == 0
    page = (Path("outputs/reports/toy_method") / "index.md").read_text()
    assert f"study run {mine} --profile smoke" in page and f"study report {mine}" in page
    runs = pd.read_csv("outputs/reports/toy_method/runs.csv")
    assert runs.command[0].split(" && ")[-1].startswith("PYTHONPATH=. ftgspp train "), runs.command[0]
    with pytest.raises(SystemExit) as err:  # a path that is no file: one line, exit 2
        main(["run", str(workdir / "nowhere.yaml")])
    assert err.value.code == 2 and "no such file" in capsys.readouterr().err
