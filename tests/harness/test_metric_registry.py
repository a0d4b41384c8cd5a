"""The metric registry: a new metric is one entry, and tables, claims and reports follow it."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
import yaml
from fakes import fake_generate, fake_train

from harness.spec import metrics
from harness.spec.metrics import LOWER, Metric

STUDY = {
    "name": "sharp", "question": "Does colour correction change the sharpness score?", "baseline": "baseline",
    "variants": {"baseline": [], "cc": ["model.color_correction=true"]},
    "table": {"layout": "variants_x_scenes", "metrics": ["sharpness"]},
    "profiles": {p: {"seeds": 3, "overrides": ["profile=smoke"], "scenes": [{"name": "easy", "synth": {}}]}
                 for p in ("quick", "paper")},
    "claims": [{"id": "cc_sharper", "claim": "Colour correction lowers the sharpness score.", "metric": "sharpness",
                "test": "mean", "a": "cc", "b": "baseline", "expect": "lower", "sesoi": 0.1,
                "sesoi_source": "a test value"}],
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
    import harness.spec.files
    from ftgspp.errors import InputError
    from harness.report.writer import write_report
    from harness.run.runner import run_study
    from harness.spec.files import load_study
    from harness.spec.runs import Selection

    studies = tmp_path / "studies"
    studies.mkdir()
    (studies / "sharp.yaml").write_text(yaml.safe_dump(STUDY))
    monkeypatch.setattr(harness.spec.files, "STUDIES_DIR", studies)
    with pytest.raises(InputError, match="unknown metric 'sharpness'"):
        load_study("sharp", studies)  # a claim may only name a registered metric

    metrics.register(Metric("sharpness", "Sharpness score", decimals=1, better=LOWER))
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
