"""The claims section of ``study report`` and ``reports/index.md`` (``study index``): on
constructed claim frames, then end to end with the fake trainer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from fakes import MINI_STUDY as MINI, fake_generate, fake_train

from harness.analysis import verdicts as V
from harness.report.claims_table import claims_latex, claims_markdown
from harness.report.fmt import p_text
from harness.report.index import StudyClaims, decide_all, index_markdown
from harness.spec.paper_register import PaperRow, Register, Statement
from harness.spec.study_schema import ClaimSpec


def frame() -> pd.DataFrame:
    rng = np.random.default_rng(0)
    base = 30 + rng.normal(0, 0.3, 6)
    df = pd.DataFrame([{"variant": v, "scene": "studio", "seed": i, "status": "FINISHED", "psnr": x}
                       for v, xs in (("baseline", base), ("cc", base + 0.5 + rng.normal(0, 0.05, 6)),
                                     ("free", base[::-1] + 0.05)) for i, x in enumerate(xs)])
    claims = [ClaimSpec("cc_mean", "CC raises the mean PSNR.", "psnr", "mean", "higher", "cc", "baseline", sesoi=0.3),
              ClaimSpec("free", "Free init changes PSNR.", "psnr", "mean", "higher", "free", "baseline", pair="none",
                        sesoi=0.05),
              ClaimSpec("gone", "Needs a variant we did not run.", "psnr", "mean", "higher", "nosuch", "baseline")]
    return V.decide(V.evaluate(df, claims, "secret5", REGISTER))


REGISTER = Register((
    Statement("s_cc", "secret 5", "CC helps.", "stability table", decided_by="secret5.cc_mean",
              numbers=(PaperRow("DyNeRF", 32.81, 32.47, 0.08, 0.22, 10),)),
    Statement("s_free", "secret 5", "Free init changes PSNR.", "table", decided_by="secret5.free"),
    Statement("s_gone", "secret 5", "Something we did not run.", "table", decided_by="secret5.gone"),
    Statement("s_real", "outdoor", "Needs real data.", "outdoor table", not_tested="needs real data (REAL_ROOT)"),
))


def test_claims_markdown_and_latex_show_effect_ci_sesoi_p_and_verdict():
    f = frame()
    md = claims_markdown(f)
    rows = [line for line in md.splitlines() if line.startswith("| **")]
    assert len(rows) == 3 and "decides `s_cc`" in rows[0]
    assert "✅ reproduced" in rows[0] and f"{f.effect[0]:+.2f} [" in rows[0] and "±0.3" in rows[0]
    assert "6 pairs" in rows[0] and "paired t" in md and "Holm over 4 hypotheses" in md
    assert f"p = {p_text(f.p_adj[0])}" in rows[0]  # the p that decided it, family-corrected
    assert "❔ inconclusive" in rows[1] and "runs/arm for 80% power at the SESOI" in rows[1]
    assert "not tested" in rows[2] and "nosuch" in rows[2]
    tex = claims_latex(f, "secret5")
    assert tex.count(r"\\") == 4 and r"\toprule" in tex and "cc\\_mean" in tex


def test_index_page_names_its_families_and_shows_the_paper_beside_us():
    f = frame()
    entries = decide_all([StudyClaims("secret5", "q", f, "secret5/index.md", 18, "abc123"),
                          StudyClaims("lpips", "q", f.iloc[:0], "lpips/index.md", 4, "abc123")])
    page = index_markdown(entries, [("Speed", "speed_accuracy/speed_accuracy.png")], ["secret3"], forest="forest.png",
                          register=REGISTER)
    rows = [line for line in page.splitlines() if line.startswith("| secret 5 |") or line.startswith("| outdoor |")]
    assert len(rows) == 4 and "[secret5](secret5/index.md)" in rows[0]  # one row per statement
    assert "32.47 ± 0.22 → 32.81 ± 0.08" in rows[0] and "distinguishable from its own spread" in rows[0]
    assert "reproduced" in rows[0] and "±0.3" in rows[0] and "DyNeRF: " in rows[0].split("|")[8]  # the size
    assert "not tested (needs real data (REAL_ROOT))" in rows[3]
    assert "**paper** (the paper's method claims): paper (every study): Holm over 4 hypotheses" in page
    assert "4 statements: 1 reproduced, 1 inconclusive, 2 not tested" in page
    assert page.index("## Families") < page.index("| secret 5 |") < page.index("![Every counted claim")
    assert "Studies with runs but no claims: [lpips](lpips/index.md)" in page
    assert "![Speed](speed_accuracy/speed_accuracy.png)" in page and "`secret3`" in page
    assert "Runs made by code abc123, trainer fingerprint unknown." in page and "More than one" not in page
    assert index_markdown(entries, [], []) == index_markdown(entries, [], [])  # no timestamp


def test_forest_plot_draws_each_tested_claim_in_sesoi_units(tmp_path: Path):
    from harness.report.forest import forest_plot, paper_points

    f = frame().assign(study="secret5")
    assert forest_plot(f, tmp_path / "forest.png").path.read_bytes()[:4] == b"\x89PNG"
    row = f.iloc[0]
    assert paper_points(row) == [("DyNeRF", pytest.approx(0.34 / 0.3))]
    lower = row.copy()
    lower["expect"] = "lower"
    assert paper_points(lower) == [("DyNeRF", pytest.approx(-0.34 / 0.3))]  # the claimed direction to the right
    assert V.in_sesoi_units(row)[0] == pytest.approx(row.effect / 0.3)


@pytest.mark.usefixtures("workdir")
def test_report_and_index_end_to_end_with_the_fake_trainer(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    import harness.spec.study_files
    from harness.cli.study import main
    from harness.report.writer import write_report
    from harness.run.runner import run_study
    from harness.spec.runs import Selection

    studies = tmp_path / "studies"
    studies.mkdir()
    (studies / "mini.yaml").write_text(yaml.safe_dump(MINI))
    (studies / "later.yaml").write_text(yaml.safe_dump({**MINI, "name": "later", "claims": []}))
    monkeypatch.setattr(harness.spec.study_files, "STUDIES_DIR", studies)
    run_study("mini", Selection(), studies_dir=studies, train_fn=fake_train, generate=fake_generate,
              echo=lambda s: None)
    write_report("mini", studies_dir=studies, reports_root=Path("reports"), echo=lambda s: None)
    claims = pd.read_csv("reports/mini/claims.csv")
    assert list(claims.id) == ["cc_mean", "cc_spread", "motion", "psnr_ssim"]
    made = pd.read_csv("reports/mini/runs.csv", dtype={"git_sha": str, "start_time": str})
    assert made.git_sha.str.fullmatch(r"[0-9a-f]{40}(-dirty)?").all()  # the commit each run was made from
    assert made.start_time.str.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z").all()  # UTC, sorts as it reads
    # these study files are in no repository: whether they were registered before the runs is unknown
    assert set(claims.registered_before_runs) == {"unknown"} and "not in a git checkout" in claims.registration_note[0]
    assert claims.verdict[2] == V.NOT_TESTED and claims.n[0] == "3 vs 3"
    assert claims.effect[0] == pytest.approx(0.5)  # the fake adds 0.5 dB with colour correction
    index = Path("reports/mini/index.md").read_text()
    assert "## Claims" in index and "cc_mean" in index
    assert Path("reports/mini/claim_psnr_ssim.png").read_bytes()[:4] == b"\x89PNG"
    assert "](claim_psnr_ssim.png)" in index and claims.n[3] == "3 pairs"
    assert "## Claims" in Path("reports/mini/table.md").read_text()
    assert "tab:mini-claims" in Path("reports/mini/table.tex").read_text()

    from harness.cli.reports_plan import plan_frame

    plan = plan_frame().set_index("study")
    assert plan.loc["mini", ["planned", "finished", "to_run"]].tolist() == [6, 6, 0]  # make reports resumes
    assert plan.loc["later", ["finished", "to_run"]].tolist() == [0, 6]
    assert main(["index", "--out", "reports"]) == 0
    page = Path("reports/index.md").read_text()
    assert sum(line.startswith("| mini |") for line in page.splitlines()) == 4
    # one verdict everywhere: the study page's claims are the index's, row for row
    index_claims = pd.read_csv("reports/claims.csv")
    pd.testing.assert_frame_equal(index_claims[index_claims.study == "mini"].drop(columns="study")
                                  .reset_index(drop=True)[["id", "verdict", "p_adj", "p_tost_adj", "family"]],
                                  claims[["id", "verdict", "p_adj", "p_tost_adj", "family"]])
    assert "[mini](mini/index.md)" in page and "`later`: `study run later --profile quick`" in page
    assert main(["index", "--out", "reports"]) == 0 and Path("reports/index.md").read_text() == page  # same page

    def rows(text: str) -> list[str]:
        return [line for line in text.splitlines() if line.startswith("| mini |")]

    Path("mlflow.db").rename("elsewhere.db")  # a checkout without the runs: the committed report speaks for them
    assert main(["index", "--out", "reports"]) == 0
    again = Path("reports/index.md").read_text()
    assert rows(again) == rows(page) and "the tracking store here having no runs of them: `mini`." in again
    assert "Read from their committed reports" not in page

    # make reports in that checkout: the committed report is current, so mini runs nothing ...
    plan = plan_frame(reports_root=Path("reports")).set_index("study")
    assert plan.loc["mini", ["finished", "to_run", "source"]].tolist() == [6, 0, "committed report"]
    assert plan.loc["later", "to_run"] == 6
    import harness.tracking.provenance as provenance

    monkeypatch.setattr(provenance, "trainer_fingerprint", lambda root=None: "0ther0ther00")
    assert plan_frame(reports_root=Path("reports")).set_index("study").loc["mini", "to_run"] == 6  # ... until the trainer changes


def test_the_run_count_line_multiplies_only_a_full_grid() -> None:
    from harness.report.writer import _grid

    full = pd.DataFrame({"variant": ["a", "a", "b", "b"], "scene": ["s"] * 4, "seed": [0, 1, 0, 1]})
    assert _grid(4, full) == "= 2 variants × 1 scenes × 2 seeds"
    # secret3's shape: each scene runs its own variants (and some fewer seeds): no product
    ragged = pd.DataFrame({"variant": ["a", "a", "b"], "scene": ["s", "s", "t"], "seed": [0, 1, 0]})
    assert _grid(3, ragged).startswith("over 2 variants, 2 scenes and 2 seeds (not every")


def test_a_profile_decides_over_all_its_runs_whatever_subset_ran_last(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """`make reports` reads every study at the quick profile: a later `study run --variants cc`
    (a new arm's runs, say) must not leave the other arms' claims untested in the index."""
    import harness.spec.study_files
    from harness.cli.study import main
    from harness.run.runner import run_study
    from harness.spec.runs import Selection

    monkeypatch.chdir(tmp_path)
    studies = tmp_path / "studies"
    studies.mkdir()
    (studies / "mini.yaml").write_text(yaml.safe_dump(MINI))
    monkeypatch.setattr(harness.spec.study_files, "STUDIES_DIR", studies)
    quiet = dict(studies_dir=studies, train_fn=fake_train, generate=fake_generate, echo=lambda s: None)
    run_study("mini", Selection(), **quiet)
    run_study("mini", Selection(variants=["cc"], seeds=4), **quiet)  # the latest invocation: one arm, one more seed
    verdict = lambda: pd.read_csv("reports/claims.csv").set_index("id").verdict["cc_mean"]  # noqa: E731
    assert main(["index", "--out", "reports"]) == 0
    assert verdict() == V.NOT_TESTED  # the latest invocation has no baseline runs
    assert main(["index", "--profile", "quick", "--out", "reports"]) == 0
    assert verdict() != V.NOT_TESTED  # the quick profile's 3 seeds of both arms
    assert main(["report", "mini", "--profile", "quick", "--out", "reports"]) == 0
    assert pd.read_csv("reports/mini/claims.csv").set_index("id").verdict["cc_mean"] == verdict()
