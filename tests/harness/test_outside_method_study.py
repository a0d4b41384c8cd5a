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
