"""'Registered before its runs' is computed from git (``spec.registration``), never written by hand:
in a throwaway repository, claim edits, arm-definition edits and register role changes move a
claim's registration commit, a ``history:`` note or a comment does not, and the runs' recorded
commits decide yes / no / unknown; the index's ⚑ and claims.csv's column are one answer."""

from __future__ import annotations

import copy
import shutil
import subprocess
from pathlib import Path

import pandas as pd
import pytest
import yaml
from fakes import MINI_STUDY

from harness.analysis import verdicts as V
from harness.report import families
from harness.report.index import index_markdown
from harness.spec import registration as R
from harness.spec.study_files import load_register, load_study

REGISTER = {"statements": [
    {"id": "s_cc", "part": "secret 5", "statement": "CC helps.", "source": "table", "decided_by": "mini.cc_mean",
     "evidence": ["mini.cc_spread"]},
    {"id": "s_pair", "part": "secret 2", "statement": "RGB is not motion.", "source": "figure",
     "decided_by": "mini.psnr_ssim"},
]}


def git(repo: Path, *args: str) -> str:
    out = subprocess.run(["git", "-C", str(repo), "-c", "user.name=t", "-c", "user.email=t@example.org", *args],
                         capture_output=True, text=True, check=True)
    return out.stdout.strip()


def commit(repo: Path, study: dict | str, register: dict, message: str) -> str:
    """Write the study file (a dict, or YAML text kept as written) and the register; commit; the sha."""
    studies = repo / "studies"
    studies.mkdir(exist_ok=True)
    (studies / "mini.yaml").write_text(study if isinstance(study, str) else yaml.safe_dump(study, sort_keys=False))
    (studies / "_paper.yaml").write_text(yaml.safe_dump(register, sort_keys=False))
    git(repo, "add", "-A")
    git(repo, "commit", "-q", "-m", message)
    R.forget()  # HEAD moved: a process reads the history once
    return git(repo, "rev-parse", "HEAD")


def runs(shas: list[str], starts: list[str] | None = None) -> pd.DataFrame:
    """Finished runs of both arms on the claims' scene, run i made at ``shas[i]``."""
    rows = []
    for i, sha in enumerate(shas):
        for v, psnr in (("baseline", 30.0 + 0.1 * i), ("cc", 30.5 + 0.13 * i)):
            rows.append({"variant": v, "scene": "easy", "seed": i, "status": "FINISHED", "psnr": psnr,
                         "ssim1": 0.9 + 0.01 * i, "git_sha": sha,
                         "start_time": (starts or [f"2026-01-0{i + 1}T00:00:00.000Z" for i in range(len(shas))])[i]})
    return pd.DataFrame(rows)


def claim(studies: Path, claim_id: str):
    return next(c for c in load_study("mini", studies).claims if c.id == claim_id)


def answer(studies: Path, claim_id: str, df: pd.DataFrame) -> R.Registration:
    return R.registration("mini", claim(studies, claim_id), df, studies)


@pytest.fixture
def repo(tmp_path: Path) -> Path:
    root = tmp_path / "repo"
    root.mkdir()
    git(root, "init", "-q")
    yield root
    R.forget()


def test_registration_follows_claim_arm_and_role_edits_but_not_notes(repo: Path) -> None:
    studies = repo / "studies"
    study = copy.deepcopy(MINI_STUDY)
    a = commit(repo, study, REGISTER, "claims registered")
    assert answer(studies, "cc_mean", runs([a, a])).before_runs == R.YES

    # notes, comments and a default written out are no change to what the claim tests
    text = yaml.safe_dump(study, sort_keys=False).replace("- id: cc_mean", "# the demo's question\n- id: cc_mean")
    text = text.replace("  claim: CC raises PSNR.", "  claim: CC raises PSNR.\n  history: [\"reworded nothing\"]\n"
                        "  group: paper")
    assert "history" in text and "# the demo" in text
    b = commit(repo, text, REGISTER, "a note and a comment")
    assert claim(studies, "cc_mean").history == ("reworded nothing",)
    assert R.history(studies).claim_commit("mini", "cc_mean") == a

    # the claim itself: a new registration; runs made before it were made before the claim
    study["claims"][0]["claim"] = "CC raises PSNR by a margin."
    c = commit(repo, study, REGISTER, "claim reworded")
    assert R.history(studies).claim_commit("mini", "cc_mean") == c
    before = answer(studies, "cc_mean", runs([b, b]))
    assert before.before_runs == R.NO and before.claim_commit == c and "came after its first run" in before.why
    assert answer(studies, "cc_mean", runs([c, c])).before_runs == R.YES

    # an arm's definition (its overrides) re-registers every claim on that arm, not the others
    study["variants"]["cc"] = ["model.color_correction=true", "init.fixed_seed=0"]
    study["variants"]["extra"] = ["lr.scale=2"]
    d = commit(repo, study, REGISTER, "cc arm redefined, an unrelated arm added")
    hist = R.history(studies)
    assert hist.claim_commit("mini", "cc_mean") == d and hist.claim_commit("mini", "psnr_ssim") == d
    assert answer(studies, "cc_mean", runs([c, c])).before_runs == R.NO

    # the register: which claim decides s_cc changes the roles of both claims it names
    moved = copy.deepcopy(REGISTER)
    moved["statements"][0].update(decided_by="mini.cc_spread", evidence=["mini.cc_mean"])
    e = commit(repo, study, moved, "cc_spread decides s_cc")
    hist = R.history(studies)
    assert (hist.claim_commit("mini", "cc_mean"), hist.role_commit("mini", "cc_mean")) == (d, e)
    assert hist.role_commit("mini", "psnr_ssim") == a and hist.role_commit("mini", "motion") == ""  # not in it
    late_role = answer(studies, "cc_mean", runs([d, d]))
    assert late_role.before_runs == R.NO and f"role at {e[:12]}" in late_role.why
    assert answer(studies, "motion", runs([d, d])).before_runs == R.YES  # an extension: no role to wait for
    assert answer(studies, "cc_mean", runs([e, e])).before_runs == R.YES

    # the earliest run decides (start_time order), and a dirty run is judged by its commit, said so
    assert answer(studies, "cc_mean", runs([e, d], ["2026-02-01T00:00:00.000Z", "2026-01-01T00:00:00.000Z"])
                  ).first_run_commit == d
    assert answer(studies, "cc_mean", runs([d, e], ["2026-02-01T00:00:00.000Z", "2026-01-01T00:00:00.000Z"])
                  ).before_runs == R.YES
    dirty = answer(studies, "cc_mean", runs([e + "-dirty"] * 2))
    assert dirty.before_runs == R.YES and "runs from uncommitted code" in dirty.why

    # git cannot say: runs without a recorded commit, a commit this clone lacks, no runs
    assert answer(studies, "cc_mean", runs([e, e]).drop(columns="git_sha")).before_runs == R.UNKNOWN
    assert answer(studies, "cc_mean", runs([e, ""])).before_runs == R.UNKNOWN
    assert "not in this clone" in answer(studies, "cc_mean", runs(["0" * 40] * 2)).why
    assert answer(studies, "cc_mean", runs([e, e]).iloc[0:0]).before_runs == R.UNKNOWN

    # an uncommitted edit registers after anything
    study["claims"][0]["claim"] = "CC raises PSNR, uncommitted."
    (studies / "mini.yaml").write_text(yaml.safe_dump(study, sort_keys=False))
    R.forget()
    now = answer(studies, "cc_mean", runs([e, e]))
    assert (now.claim_commit, now.before_runs) == (R.NOT_COMMITTED, R.NO)
    assert answer(studies, "cc_spread", runs([e, e])).before_runs == R.YES  # its neighbour is committed as it is


def test_a_hand_written_registration_is_no_longer_a_key(tmp_path: Path) -> None:
    from ftgspp.errors import InputError

    study = copy.deepcopy(MINI_STUDY)
    study["claims"][0]["registered"] = "after the runs"
    (tmp_path / "mini.yaml").write_text(yaml.safe_dump(study))
    with pytest.raises(InputError, match="unknown key.*registered"):
        load_study("mini", tmp_path)


def test_without_the_history_the_answer_is_unknown_never_a_guess(repo: Path, tmp_path: Path) -> None:
    a = commit(repo, copy.deepcopy(MINI_STUDY), REGISTER, "one")
    b = commit(repo, {**copy.deepcopy(MINI_STUDY), "question": "Reworded question?"}, REGISTER, "two")
    shallow = tmp_path / "shallow"
    subprocess.run(["git", "clone", "-q", "--depth", "1", f"file://{repo}", str(shallow)], check=True,
                   capture_output=True)
    got = answer(shallow / "studies", "cc_mean", runs([b, b]))
    assert (got.before_runs, got.claim_commit) == (R.UNKNOWN, "") and "shallow clone" in got.why
    loose = tmp_path / "loose"  # the study files without any repository
    shutil.copytree(repo / "studies", loose)
    got = answer(loose, "cc_mean", runs([a, a]))
    assert got.before_runs == R.UNKNOWN and "not in a git checkout" in got.why


def test_the_index_mark_and_claims_csv_are_one_computed_answer(repo: Path, tmp_path: Path) -> None:
    studies = repo / "studies"
    study = copy.deepcopy(MINI_STUDY)
    a = commit(repo, study, REGISTER, "claims registered")
    study["claims"][1]["claim"] = "CC lowers the run-to-run spread."  # cc_spread rewritten after the runs
    commit(repo, study, REGISTER, "cc_spread reworded")
    root = tmp_path / "reports"
    (root / "mini").mkdir(parents=True)
    runs([a, a, a]).to_csv(root / "mini" / "runs.csv", index=False)
    entry = families.report_claims("mini", root, load_register(studies), studies)
    [decided] = families.decide_all([entry])
    by = decided.frame.set_index("id")
    assert by.loc["cc_mean", "registered_before_runs"] == R.YES and by.loc["cc_mean", "registered_commit"] == a
    assert by.loc["cc_spread", "registered_before_runs"] == R.NO and by.loc["cc_spread", "first_run_commit"] == a
    assert not by.loc["cc_spread", "exploratory"]  # evidence: marked, but in no family, so not "exploratory"
    assert by.loc["motion", "role_commit"] == ""
    page = index_markdown([decided], [], [], register=load_register(studies))
    evidence = next(line for line in page.splitlines() if line.startswith("| secret 5 |"))
    assert "`mini.cc_spread`" in evidence and "⚑" in evidence.split("`mini.cc_spread`")[1]
    assert "⚑" not in evidence.split("`mini.cc_spread`")[0]  # the deciding claim was registered before


@pytest.mark.slow
@pytest.mark.usefixtures("workdir")  # an empty tracking store: every study is read from its committed report
def test_on_the_committed_reports_the_index_marks_exactly_what_claims_csv_computes(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from harness.report.index import write_claims_index
    from harness.spec.study_files import STUDIES_DIR

    monkeypatch.setattr(families, "COMMITTED_REPORTS", Path(__file__).resolve().parents[2] / "reports")
    out = tmp_path / "reports"
    write_claims_index(out, echo=lambda s: None, profile="quick")
    claims = pd.read_csv(out / "claims.csv", keep_default_na=False)
    assert set(claims.registered_before_runs) <= {R.YES, R.NO, R.UNKNOWN}
    late = claims.registered_before_runs == R.NO
    decided = (claims.counted.astype(str) == "True") & claims.verdict.isin(V.DECIDED)
    assert (claims.exploratory.astype(str) == "True").tolist() == (late & decided).tolist()
    lines = (out / "index.md").read_text().splitlines()
    marked, computed = set(), set(claims[late].study + "." + claims[late].id)
    for _, r in claims.iterrows():  # a row of its own (this project's claims) or inside a statement's row
        ref = f"{r.study}.{r.id}"
        own = [line for line in lines if line.startswith(f"| {r.study} | **{r.id}**:")]
        inside = [line.split(f"`{ref}`: ", 1)[1].split("<br>")[0].split(" | ")[0] for line in lines
                  if f"`{ref}`: " in line]
        if any("⚑" in text for text in own + inside):
            marked.add(ref)
    for s in load_register(STUDIES_DIR).statements:  # the deciding row, in both tables of statements
        deciding = claims[claims.study + "." + claims.claim == s.decided_by]
        for line in lines:
            if line.startswith(f"| **{s.id}**:") or line.startswith(f"| {s.part} | **{s.id}**:"):
                verdict = line.split(" | ")[3 if line.startswith("| **") else 6]
                if "⚑" in verdict:
                    marked.update(deciding.study + "." + deciding.id)
                assert ("⚑" in verdict) == bool((deciding.registered_before_runs == R.NO).any()), line
    assert marked == computed
    unknown = int((claims[claims.counted.astype(str) == "True"].registered_before_runs == R.UNKNOWN).sum())
    assert any(line.startswith("Registered before their runs, computed from git") and
               (f"unknown: {unknown} (" in line if unknown else "unknown" not in line) for line in lines)
