"""The claims section of ``study report`` and ``reports/index.md`` (``study index``): on
constructed claim frames, then end to end with the fake trainer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from fakes import fake_generate, fake_train

from harness.analysis import claims as C
from harness.report.claims import claims_latex, claims_markdown
from harness.report.index import StudyClaims, index_markdown
from harness.spec.study import ClaimSpec

MINI = {
    "name": "mini",
    "question": "Does colour correction help the fake trainer?",
    "baseline": "baseline",
    "variants": {"baseline": [], "cc": ["model.color_correction=true"]},
    "metrics": ["psnr"],
    "plots": [],
    "claims": [
        {"id": "cc_mean", "claim": "CC raises PSNR.", "paper_number": "+0.3 dB", "metric": "psnr", "test": "mean",
         "a": "cc", "b": "baseline", "expect": "higher", "pair": "none"},
        {"id": "cc_spread", "claim": "CC lowers the spread.", "metric": "psnr", "test": "variance", "a": "cc",
         "b": "baseline", "expect": "lower"},
        {"id": "motion", "claim": "Not logged by the fake.", "metric": "flicker_static", "test": "mean", "a": "cc",
         "b": "baseline", "expect": "lower"},
        {"id": "psnr_ssim", "claim": "PSNR and SSIM are weakly related.", "metric": "psnr", "versus": "ssim1",
         "test": "correlation", "expect": "weak"},
    ],
    "profiles": {
        "quick": {"seeds": 3, "overrides": ["profile=smoke"], "expected_runtime": "seconds", "command": "study run mini",
                  "scenes": [{"name": "easy", "synth": {"preset": "studio", "seed": 0}}]},
        "paper": {"seeds": 2, "overrides": ["profile=paper"], "scenes": [{"name": "real", "overrides": ["data.path=/x"]}]},
    },
}


def frame() -> pd.DataFrame:
    rng = np.random.default_rng(0)
    base = 30 + rng.normal(0, 0.3, 6)
    df = pd.DataFrame([{"variant": v, "scene": "studio", "seed": i, "status": "FINISHED", "psnr": x}
                       for v, xs in (("baseline", base), ("cc", base + 0.5 + rng.normal(0, 0.05, 6)),
                                     ("free", base[::-1] + 0.05)) for i, x in enumerate(xs)])
    claims = [ClaimSpec("cc_mean", "CC raises the mean PSNR.", "psnr", "mean", "higher", "cc", "baseline",
                        paper_number="+0.3 dB"),
              ClaimSpec("free", "Free init changes PSNR.", "psnr", "mean", "higher", "free", "baseline", pair="none"),
              ClaimSpec("gone", "Needs a variant we did not run.", "psnr", "mean", "higher", "nosuch", "baseline")]
    return C.evaluate(df, claims)


def test_claims_markdown_and_latex_show_effect_ci_p_and_verdict():
    f = frame()
    md = claims_markdown(f)
    rows = [line for line in md.splitlines() if line.startswith("| **")]
    assert len(rows) == 3 and "| — |" in rows[1]  # no paper number
    assert "+0.3 dB" in rows[0] and "✅ reproduced" in rows[0] and f"{f.effect[0]:+.2f} [" in rows[0]
    assert "6 pairs" in rows[0] and "paired t" in md and "Holm" in md
    assert "❔ inconclusive" in rows[1] and rows[1].rstrip(" |").split("|")[-1].strip().isdigit()  # n for power
    assert "not tested" in rows[2] and "nosuch" in rows[2]
    tex = claims_latex(f, "secret5")
    assert tex.count(r"\\") == 4 and r"\toprule" in tex and "cc\\_mean" in tex


def test_index_page_has_a_row_per_claim_charts_and_missing_studies():
    f = frame()
    entries = [StudyClaims("secret5", "q", f, "secret5/index.md", 18, "abc123"),
               StudyClaims("lpips", "q", f.iloc[:0], "lpips/index.md", 4, "abc123")]
    page = index_markdown(entries, [("Speed", "speed_accuracy/speed_accuracy.png")], ["secret3"])
    rows = [line for line in page.splitlines() if line.startswith("| secret5 |")]
    assert len(rows) == 3 and all("[secret5](secret5/index.md)" in r for r in rows)
    assert f"({f.n[0]}, p = " in rows[0] and "+0.3 dB" in rows[0] and "reproduced" in rows[0]
    assert "runs/arm for 80% power" in rows[1] and "−" not in claims_latex(f, "s")
    assert "| lpips | (no claims stated)" in page
    assert "![Speed](speed_accuracy/speed_accuracy.png)" in page and "`secret3`" in page
    assert "Runs made by code abc123." in page and "More than one" not in page
    assert index_markdown(entries, [], []) == index_markdown(entries, [], [])  # no timestamp


@pytest.mark.usefixtures("workdir")
def test_report_and_index_end_to_end_with_the_fake_trainer(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    import harness.spec.files
    from harness.cli.study import main
    from harness.report.writer import write_report
    from harness.run.runner import run_study
    from harness.spec.runs import Selection

    studies = tmp_path / "studies"
    studies.mkdir()
    (studies / "mini.yaml").write_text(yaml.safe_dump(MINI))
    (studies / "later.yaml").write_text(yaml.safe_dump({**MINI, "name": "later", "claims": []}))
    monkeypatch.setattr(harness.spec.files, "STUDIES_DIR", studies)
    run_study("mini", Selection(), studies_dir=studies, train_fn=fake_train, generate=fake_generate,
              echo=lambda s: None)
    write_report("mini", studies_dir=studies, reports_root=Path("reports"), echo=lambda s: None)
    claims = pd.read_csv("reports/mini/claims.csv")
    assert list(claims.id) == ["cc_mean", "cc_spread", "motion", "psnr_ssim"]
    assert claims.verdict[2] == C.NOT_TESTED and claims.n[0] == "3 vs 3"
    assert claims.effect[0] == pytest.approx(0.5)  # the fake adds 0.5 dB with colour correction
    index = Path("reports/mini/index.md").read_text()
    assert "## Claims" in index and "cc_mean" in index
    assert Path("reports/mini/claim_psnr_ssim.png").read_bytes()[:4] == b"\x89PNG"
    assert "](claim_psnr_ssim.png)" in index and claims.n[3] == "6 runs"
    assert "## Claims" in Path("reports/mini/table.md").read_text()
    assert "tab:mini-claims" in Path("reports/mini/table.tex").read_text()

    from harness.cli.reports_plan import plan_frame

    plan = plan_frame().set_index("study")
    assert plan.loc["mini", ["planned", "finished", "to_run"]].tolist() == [6, 6, 0]  # make reports resumes
    assert plan.loc["later", ["finished", "to_run"]].tolist() == [0, 6]
    assert main(["index", "--out", "reports"]) == 0
    page = Path("reports/index.md").read_text()
    assert sum(line.startswith("| mini |") for line in page.splitlines()) == 4
    assert "[mini](mini/index.md)" in page and "`later`: `study run later --profile quick`" in page
    assert main(["index", "--out", "reports"]) == 0 and Path("reports/index.md").read_text() == page  # same page
