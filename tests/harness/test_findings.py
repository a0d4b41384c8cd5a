"""FINDINGS.md cannot drift from the reports: every decimal it cites names the generated number,
a whole number it tags is checked like a decimal, and a sentence cannot state a direction its
number contradicts."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from harness.report.findings import check, collect_findings

ROOT = Path(__file__).resolve().parents[2]


def _reports(tmp_path: Path) -> Path:
    (tmp_path / "secret5").mkdir()
    pd.DataFrame([{"variant": "baseline", "scene": "studio", "metric": "psnr", "mean": 29.2413, "std": 0.2614,
                   "ci95": 0.32},
                  {"variant": "cc", "scene": "studio", "metric": "psnr", "mean": 29.2612, "std": 0.11, "ci95": 0.14}]
                 ).to_csv(tmp_path / "secret5" / "summary.csv", index=False)
    pd.DataFrame([{"study": "secret5", "id": "cc_raises_mean", "effect": 0.0199, "ci_low": -0.5, "ci_high": 0.55,
                   "sesoi": 0.34, "p": 0.9, "p_adj": 1.0, "p_tost_adj": 0.7, "n_needed": 15}]
                 ).to_csv(tmp_path / "claims.csv", index=False)
    pd.DataFrame([{"variant": "cc", "scene": "studio", "seed": s, "status": st, "relocated_total": r}
                  for s, st, r in ((0, "FINISHED", 1500), (1, "FINISHED", 1600), (2, "FINISHED", 1900),
                                   (3, "FAILED", 10))]).to_csv(tmp_path / "secret5" / "runs.csv", index=False)
    pd.DataFrame([{"component": "hardware (kernel dispatch)", "sd": 0.069}]).to_csv(tmp_path / "secret5" / "variance.csv",
                                                                                   index=False)
    return tmp_path


def test_a_cited_number_must_name_the_generated_value_it_comes_from(tmp_path: Path) -> None:
    f = collect_findings(_reports(tmp_path))
    assert f["secret5.psnr.cc.studio.std"] == 0.11 and f["secret5.claims.cc_raises_mean.sesoi"] == 0.34
    assert f["secret5.psnr.diff.studio.cc-baseline"] == 29.2612 - 29.2413
    assert f["secret5.median.relocated_total.cc.studio"] == 1600  # finished runs only
    assert (f["secret5.min.relocated_total.cc.studio"], f["secret5.max.relocated_total.cc.studio"]) == (1500, 1900)
    assert "secret5.median.seed.cc.studio" not in f
    assert f["secret5.variance.hardware_kernel_dispatch.sd"] == 0.069  # a key has no spaces or brackets
    assert (f["paper.ab_flow.DyNeRF.b"], f["paper.ab_flow.DyNeRF.a"]) == (32.62, 32.73)  # the paper register
    assert f["paper.out_ftgspp.Google_Immersive.effect"] == pytest.approx(22.68 - 22.29)
    assert f["paper.s5_cc_spread.DyNeRF.sd_ratio"] == pytest.approx(0.08 / 0.22)
    good = ("Run-to-run SD 0.26<!--secret5.psnr.baseline.studio.std--> dB against 0.11<!--secret5.psnr.cc.studio.std-->;"
            " CC +0.02<!--secret5.claims.cc_raises_mean.effect--> dB (SESOI ±0.34<!--secret5.claims.cc_raises_mean.sesoi-->),"
            " a gap of 0.020<!--secret5.psnr.diff.studio.baseline-cc|abs--> dB. Commit `7fae4f1`, 5 seeds.")
    assert check(good, f) == []
    assert check("fast motion costs 0.8–1.0 dB", f) == ["0.8: no key says which generated number it is",
                                                         "1.0: no key says which generated number it is"]
    wrong = check("SD 0.27<!--secret5.psnr.baseline.studio.std--> and 1.5<!--nosuch.key-->", f)
    assert wrong == ["0.27: secret5.psnr.baseline.studio.std is 0.2614", "1.5: unknown key nosuch.key"]


def test_the_committed_findings_cite_only_what_the_committed_reports_hold() -> None:
    import json

    reports = ROOT / "reports"
    findings = json.loads((reports / "findings.json").read_text())
    assert findings == collect_findings(reports)  # findings.json is generated, not edited
    assert check((reports / "FINDINGS.md").read_text(), findings) == []


def test_a_wrong_whole_number_or_a_flipped_direction_fails(tmp_path: Path) -> None:
    f = collect_findings(_reports(tmp_path))
    f["secret5.claims.cc_lowers_spread.effect"], f["secret5.claims.cc_lowers_spread.centre"] = 1.61, 1.0
    median = "secret5.median.relocated_total.cc.studio"
    assert check(f"a median of 1,600<!--{median}--> relocations over 5 seeds", f) == []
    assert check(f"a median of 1,532<!--{median}--> relocations", f) == [f"1532: {median} is 1600.00"]
    ratio = "secret5.claims.cc_lowers_spread.effect"
    assert check(f"Colour correction raises the spread: ×1.61<!--{ratio}-->.", f) == []
    assert check(f"Colour correction does not lower the spread (×1.61<!--{ratio}-->).", f) == []
    assert check(f"Colour correction lowers the spread (×1.61<!--{ratio}-->).", f) == [
        f"×1.61: the sentence says down, but {ratio} is 1.61 (a ratio: against 1)"]
    effect = "secret5.claims.cc_raises_mean.effect"
    assert check(f"CC raises the mean by +0.02<!--{effect}--> dB.", f) == []
    assert check(f"CC lowers the mean by +0.02<!--{effect}--> dB.", f) != []


def test_the_committed_findings_read_in_minutes_and_cite_the_adjusted_intervals() -> None:
    """FINDINGS.md stays short (its history lives in docs/findings-history.md), and a claim's
    Holm-adjusted interval is a key it can cite, so its intervals are the ones the verdicts use."""
    text = (ROOT / "reports" / "FINDINGS.md").read_text()
    assert len(text.encode()) <= 15_000
    assert "claims.ssim_range2_higher.ci_adj_low" in text
    f = collect_findings(ROOT / "reports")
    claims = pd.read_csv(ROOT / "reports" / "claims.csv")
    # a decided row's Holm-adjusted interval is a key (the conventions' SSIM row: decided at fixed n)
    row = claims[(claims.study == "lpips") & (claims.id == "ssim_range2_higher")].iloc[0]
    assert row.ci_adj_level > 0.95 and f["lpips.claims.ssim_range2_higher.ci_adj_low"] == pytest.approx(row.ci_adj_low)
    assert (ROOT / "docs" / "findings-history.md").read_text().count("\n## Findings") >= 2


def test_a_scenes_fresh_instances_are_one_cell_of_the_medians(tmp_path: Path) -> None:
    from harness.report.findings import _medians

    rows = [{"variant": "base", "scene": "studio", "instance_of": "studio", "instance": 0, "seed": s,
             "status": "FINISHED", "psnr": 30.0 + s} for s in range(3)]
    rows += [{"variant": "base", "scene": f"studio@{i}", "instance_of": "studio", "instance": i, "seed": 0,
              "status": "FINISHED", "psnr": 20.0 + i} for i in range(1, 6)]
    pd.DataFrame(rows).to_csv(tmp_path / "runs.csv", index=False)
    out: dict[str, float] = {}
    _medians("mine", tmp_path / "runs.csv", out)
    assert out["mine.median.psnr.base.studio"] == 31.0  # the scene as written: its seeds
    assert (out["mine.median.psnr.base.studio@fresh"], out["mine.min.psnr.base.studio@fresh"]) == (23.0, 21.0)
    assert not [k for k in out if "@" in k and not k.endswith("@fresh")]  # no cell per instance
