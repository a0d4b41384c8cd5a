"""End to end with the real trainer: ``study run secret5 --profile smoke`` then ``study report``."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from harness.cli.study import main
from harness.tracking.records import load_runs, open_store

pytestmark = pytest.mark.slow


def test_secret5_smoke_run_report_and_resume(workdir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = ["run", "secret5", "--profile", "smoke", "--variants", "baseline"]
    assert main(args) == 0
    store = open_store(f"sqlite:///{Path('mlflow.db').resolve()}")
    (rec,) = load_runs(store, "ftgspp/secret5", "secret5")
    assert rec.status == "FINISHED", rec.tags.get("error")
    for key in ("psnr", "ssim1", "ssim2", "dssim1", "dssim2", "train_seconds", "iters_per_second", "peak_rss_mb"):
        assert math.isfinite(rec.metrics[key]), key
    assert rec.metrics["n_gaussians"] == 300  # the smoke profile's budget
    assert rec.params["profile"] == "smoke" and rec.tags["device"] == "cpu"
    assert store.client.get_metric_history(rec.run_id, "loss")
    files = {a.path for a in store.client.list_artifacts(rec.run_id)}
    assert "config.yaml" in files and "renders" in files
    assert (Path("data/synth/studio-smoke") / ".study_synth.json").is_file()

    capsys.readouterr()
    assert main(args) == 0
    assert "1 already finished, 0 to run" in capsys.readouterr().out
    assert main(["report", "secret5"]) == 0
    report = Path("outputs/reports/secret5")
    for name in ("index.md", "table.md", "table.tex", "strip_psnr.png"):
        assert (report / name).is_file(), name
    assert "| baseline |" in (report / "table.md").read_text()


# One non-baseline variant of every study (so the gate, flow init, colour correction,
# relocation policies, budget/iteration grids and difficulty cells all run), smoke profile.
SMOKE_VARIANT = {
    "secret1": "gate_bound", "secret2": None, "secret3": None, "secret4": "partial_copy",
    "lpips": "baseline", "ablation": None, "stability": None, "speed_accuracy": None,
}


@pytest.mark.parametrize("study", sorted(SMOKE_VARIANT))
def test_every_study_runs_and_reports_at_smoke_scale(study: str, workdir: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    from harness.spec.study_files import load_study

    spec = load_study(study).profile("smoke")
    variant = SMOKE_VARIANT[study] or list(spec.variants)[-1]  # the most complete variant
    scene = next(s.name for s in spec.scenes if not s.variants or variant in s.variants)
    assert main(["run", study, "--profile", "smoke", "--variants", variant, "--scenes", scene]) == 0
    out = capsys.readouterr().out
    assert "0 failed" in out, out[-2000:]
    assert main(["report", study]) == 0
    assert (Path("outputs/reports") / study / "table.md").is_file() and not Path("reports").exists()
