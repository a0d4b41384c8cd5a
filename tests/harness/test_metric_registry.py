"""The metric registry: a new metric is one entry, and tables, claims and reports follow it;
every metric a real run logs has an entry, and the harness's lists of metrics come from it."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
import yaml
from fakes import fake_generate, fake_train

from ftgspp.config import TrainConfig
from ftgspp.image_metrics import METRICS as IMAGE_METRICS
from ftgspp.tracker import NullTracker
from harness.spec import metrics
from harness.spec.metrics import EVALUATION, LOWER, Metric

STUDY = {
    "name": "sharp", "question": "Does colour correction change the sharpness score?", "baseline": "baseline",
    "variants": {"baseline": [], "cc": ["model.color_correction=true"]},
    "table": {"layout": "variants_x_scenes", "metrics": ["sharpness"]},
    "profiles": {p: {"seeds": 3, "overrides": ["profile=smoke"], "scenes": [{"name": "easy", "synth": {}}]}
                 for p in ("quick", "paper")},
    "claims": [{"id": "cc_sharper", "claim": "Colour correction lowers the sharpness score.", "metric": "sharpness",
                "test": "mean", "a": "cc", "b": "baseline", "scenes": ["easy"], "expect": "lower"}],
}


def sharp_train(cfg, out_dir, tracker):
    """The fake trainer, plus a metric no entry of the registry knows yet (cc lowers it by 0.25)."""
    result = fake_train(cfg, out_dir, tracker)
    result.metrics["sharpness"] = 3.0 + 0.1 * cfg.seed - 0.25 * cfg.model.color_correction
    return result


def test_lookup_knows_exact_names_families_and_unknown_names() -> None:
    assert (metrics.title("psnr"), metrics.decimals("psnr")) == ("PSNR (dB) ↑", 2)
    assert metrics.title("lpips_alex") == "LPIPS-Alex ([-1,1] input) ↓"
    assert (metrics.decimals("lpips_squeeze"), metrics.lower_is_better("lpips_squeeze")) == (4, True)
    assert metrics.title("gap_ssim") == "SSIM: data range 2 − 1"  # a difference has no better side
    assert (metrics.title("mystery"), metrics.decimals("mystery")) == ("mystery ↑", 3)
    df = pd.DataFrame({"ssim1": [0.8], "ssim2": [0.9]})
    assert metrics.add_differences(df).gap_ssim.tolist() == pytest.approx([0.1])


@pytest.mark.usefixtures("workdir")
def test_a_new_metric_is_one_registry_entry(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import harness.spec.study_files
    from ftgspp.errors import InputError
    from harness.report.writer import write_report
    from harness.run.runner import run_study
    from harness.spec.runs import Selection
    from harness.spec.study_files import load_study

    studies = tmp_path / "studies"
    studies.mkdir()
    (studies / "sharp.yaml").write_text(yaml.safe_dump(STUDY))
    monkeypatch.setattr(harness.spec.study_files, "STUDIES_DIR", studies)
    with pytest.raises(InputError, match="unknown metric 'sharpness'"):
        load_study("sharp", studies)  # a claim may only name a registered metric

    metrics.register(Metric("sharpness", "Sharpness score", decimals=1, better=LOWER))
    with pytest.raises(InputError, match="no smallest effect of interest"):
        load_study("sharp", studies)  # a claim needs its metric's smallest effect of interest
    metrics.register(Metric("sharpness", "Sharpness score", decimals=1, better=LOWER, smallest_effect=0.1,
                            sesoi_scale="sharpness"))
    try:
        run_study("sharp", Selection(), studies_dir=studies, train_fn=sharp_train, generate=fake_generate,
                  echo=lambda s: None)
        write_report("sharp", studies_dir=studies, reports_root=Path("reports"), echo=lambda s: None)
    finally:
        metrics.unregister("sharpness")
    table = Path("reports/sharp/table.md").read_text()
    assert "## Sharpness score ↓" in table  # its label and direction
    assert "| cc | **2.9 ± 0.1** |" in table and "| baseline | 3.1 ± 0.1 |" in table  # 1 decimal, lower is best
    claims = pd.read_csv("reports/sharp/claims.csv").set_index("id")
    assert claims.loc["cc_sharper", "effect"] == pytest.approx(-0.25)
    assert "Sharpness score ↓" in Path("reports/sharp/index.md").read_text()


class LoggedNames(NullTracker):
    """A tracker that keeps the name of every metric the trainer logs, per step and final."""

    def __init__(self) -> None:
        self.names: set[str] = set()

    def log_metrics(self, metrics: dict[str, float], step: int | None = None) -> None:
        self.names.update(metrics)


def tiny_cfg(scene_dir: Path, out_dir: Path) -> TrainConfig:
    """20 iterations of 400 Gaussians on the CPU, logging every 5, relocating every 10, colour
    correction on (its step metrics), LPIPS and diagnostics as a study run has them."""
    cfg = TrainConfig(iterations=20, budget=400, backend="cpu", progress=False, log_every=5, out_dir=str(out_dir))
    cfg.data.path = str(scene_dir)
    cfg.model.color_correction = True
    cfg.init.keyframe_stride = 3
    cfg.strategy.refine_every, cfg.strategy.refine_start_iter, cfg.strategy.refine_stop_iter = 10, 5, 15
    return cfg


@pytest.fixture(scope="module")
def logged(tiny_scene_dir: Path, tiny_scene, lpips_weights: Path, tmp_path_factory: pytest.TempPathFactory) -> set[str]:
    """Every metric name two tiny real runs log: a finished one (step metrics, evaluation, LPIPS,
    timings, diagnostics) and one that diverges at its first step."""
    import ftgspp.trainer
    from ftgspp.trainer import train

    out = tmp_path_factory.mktemp("logged")
    names: set[str] = set()
    tracker = LoggedNames()
    finished = train(tiny_cfg(tiny_scene_dir, out / "finished"), tiny_scene, tracker)
    assert finished.status == "FINISHED"
    names |= tracker.names | set(finished.metrics)

    real = ftgspp.trainer.photometric

    def poisoned(pred, gt, w):  # a NaN loss at the first step
        loss, l1 = real(pred, gt, w)
        return loss * float("nan"), l1

    tracker = LoggedNames()
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(ftgspp.trainer, "photometric", poisoned)
        diverged = train(tiny_cfg(tiny_scene_dir, out / "diverged"), tiny_scene, tracker)
    assert diverged.failure == "diverged"
    return names | tracker.names | set(diverged.metrics)


def test_every_metric_a_real_run_logs_has_a_registry_entry(logged: set[str]) -> None:
    # the runs reached every source: steps, held-out evaluation, LPIPS, timings, diagnostics, failure
    assert {"loss", "cc_mean_delta", "relocated", "psnr_cc", "lpips_vgg_01", "eval_frames", "init_seconds",
            "motion_epe_dynamic", "flicker_static", "diverged_at"} <= logged
    assert metrics.unregistered(logged) == []  # an exact entry or a family pattern, never the fallback


def test_the_check_reports_a_planted_unregistered_metric(logged: set[str]) -> None:
    assert metrics.unregistered(logged | {"sharpness", "lpips_squeeze"}) == ["sharpness"]  # a family covers lpips_*
    assert metrics.lookup("sharpness").title == "sharpness ↑"  # what the fallback would have shown
    metrics.register(Metric("sharpness", "Sharpness score", decimals=1, better=LOWER))
    try:
        assert metrics.unregistered(logged | {"sharpness"}) == []
    finally:
        metrics.unregister("sharpness")


def test_each_image_metric_is_an_entry_computed_by_its_ftgspp_evaluator() -> None:
    computed = {m.name: m.compute for m in metrics.entries() if m.compute is not None}
    assert computed == IMAGE_METRICS  # the same evaluator objects, every one of them, no other
    assert all(metrics.lookup(name).source == EVALUATION for name in IMAGE_METRICS)
    assert list(computed) == list(IMAGE_METRICS)  # ``ftgspp metrics`` and the tables list them alike


def test_units_are_what_the_labels_end_with() -> None:
    for m in metrics.entries():
        assert not m.unit or m.label.endswith(f"({m.unit})"), m.name
        assert (m.smallest_effect is None) == (m.name not in metrics.SMALLEST_EFFECTS), m.name
        assert m.smallest_effect is None or m.smallest_effect > 0 and m.sesoi_scale, m.name


def test_every_claimable_metric_a_study_claims_on_has_a_documented_smallest_effect() -> None:
    from harness.spec.study_files import list_studies, load_study

    doc = (Path(__file__).resolve().parents[2] / "docs" / "sesoi.md").read_text()
    for name in list_studies():
        for c in load_study(name).claims:
            value, scale = metrics.sesoi(c.metric, c.test)
            assert c.sesoi == value and f'id="{scale}"' in doc, (name, c.id)  # one value per metric, its rationale


def test_the_harness_lists_of_metrics_come_from_the_registry(capsys: pytest.CaptureFixture[str]) -> None:
    from harness.analysis import budget_search
    from harness.cli.study import build_parser
    from harness.tracking.conventions import VIEW_METRICS

    # the budget search judges the held-out metrics in dB; the report names them as the registry does
    assert metrics.budget_metrics() == ("psnr", "psnr_cc")
    assert budget_search.METRICS == {"psnr": "held-out PSNR", "psnr_cc": "colour-aligned held-out PSNR"}
    assert list(budget_search.METRICS) == [m for m in metrics.names() if metrics.lookup(m).unit == "dB"
                                           and metrics.lookup(m).source == EVALUATION]
    parser = build_parser()
    for m in metrics.budget_metrics():  # `study budget --metric` accepts exactly those
        assert parser.parse_args(["budget", "--preset", "studio", "--metric", m]).metric == m
    with pytest.raises(SystemExit):
        parser.parse_args(["budget", "--preset", "studio", "--metric", "ssim1"])
    assert "invalid choice: 'ssim1' (choose from 'psnr', 'psnr_cc')" in capsys.readouterr().err
    # the MLflow view's columns (tracking imports no other wing, so checked here): exact entries
    assert set(VIEW_METRICS) <= set(metrics.names())
    # a run's phase timings (benchmarks/runs_per_hour.py), in the order they run
    assert metrics.phases() == ("init_seconds", "train_seconds", "eval_seconds", "eval_lpips_seconds",
                                "diagnostics_seconds")
