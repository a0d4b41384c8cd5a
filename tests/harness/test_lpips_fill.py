"""A run scored without LPIPS (weights missing) says so, and a later run with the weights fills it in."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import TOY_STUDIES
from fakes import fake_generate, fake_train

from harness.run.runner import run_study
from harness.spec.runs import Selection
from harness.tracking.records import load_runs, open_store

WEIGHTS = {"present": False}


def train_without_weights(cfg, out_dir, tracker):
    result = fake_train(cfg, out_dir, tracker)
    if not WEIGHTS["present"]:  # what ftgspp.evaluate.evaluate_lpips returns without weights
        result.metrics = {k: v for k, v in result.metrics.items() if not k.startswith("lpips")}
        result.metrics["lpips_missing"] = 1.0
    return result


def test_a_run_without_lpips_is_run_again_once_the_weights_exist(workdir: Path, monkeypatch: pytest.MonkeyPatch):
    import ftgspp.lpips

    monkeypatch.setattr(ftgspp.lpips, "weights_present", lambda *a, **k: WEIGHTS["present"])
    sel = Selection(variants=["baseline"], seeds=1)
    kw = dict(studies_dir=TOY_STUDIES, train_fn=train_without_weights, generate=fake_generate, echo=lambda s: None)
    assert run_study("toy", sel, **kw).launched == 1
    assert run_study("toy", sel, **kw).launched == 0  # still no weights: nothing to gain
    WEIGHTS["present"] = True
    try:
        assert run_study("toy", sel, **kw).launched == 1  # the weights arrived: score it again
        assert run_study("toy", sel, **kw).launched == 0
    finally:
        WEIGHTS["present"] = False
    store = open_store(f"sqlite:///{Path('mlflow.db').resolve()}")
    latest = load_runs(store, "ftgspp/toy", "toy")[-1]
    assert "lpips_alex" in latest.metrics and "lpips_missing" not in latest.metrics
