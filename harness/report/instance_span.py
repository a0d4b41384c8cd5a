"""How many scene instances each counted method claim's runs span (issue 57; docs/sequential.md).

A method claim about a kind of scene needs several instances of it (``spec.instances``); seeds on
one instance are technical replicates. ``committed_spans()`` lists, for every counted method
claim — group ``paper`` or ``extension``, a mean, contrast or interaction claim, counted in its
family (not withdrawn, not evidence for or replaced in the paper register) and not a run-to-run
claim — how many
instances of each of its scenes the runs its test reads (fresh instances, once any ran: the
pilot instance 0 is left out) in the committed reports (``reports/<study>/runs.csv``)
span; ``claim_spans`` does it for one study's claims and runs frame.

A run-to-run claim is about repeated optimisation of one fixed scene (the paper's secret 5: the
initialisation fixed, only the seed varies) and keeps the seed as its unit: a claim that says
``unit: seed``, and every mean claim of the studies in ``RUN_TO_RUN_STUDIES`` (their files predate
``unit:``). The instance columns come from the study files (``spec.instances.instance_columns``),
so a ``runs.csv`` written before they existed reads as instance 0 of each scene.

    from harness.report.instance_span import committed_spans
    spans = committed_spans()
    assert (spans.instances >= 3).all(), spans[spans.instances < 3]   # "every method claim spans 3"
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from harness.analysis.instance_unit import instances_spanned, tested_runs
from harness.analysis.sequential_study import counts_in_group
from harness.report import COMMITTED_REPORTS
from harness.spec.instances import instance_columns, takes_instances
from harness.spec.metrics import add_differences
from harness.spec.paper_register import Register
from harness.spec.study_files import list_studies, load_register, load_study
from harness.spec.study_schema import ClaimGroup, ClaimSpec, Unit

METHOD_GROUPS = (ClaimGroup.paper, ClaimGroup.extension)
RUN_TO_RUN_STUDIES = ("secret5", "secret5_cc")  # the paper's secret 5 protocol: one fixed scene, seeds vary
COLUMNS = ["study", "claim", "group", "scenes", "instances", "most_instances", "per_scene", "runs"]


def run_to_run(study: str, claim: ClaimSpec) -> bool:
    """Does the claim keep the seed as its unit (``unit: seed``, or a secret 5 study's claim)?"""
    return claim.unit == Unit.seed or study in RUN_TO_RUN_STUDIES


def method_claim(study: str, claim: ClaimSpec, register: Register) -> bool:
    """A counted method claim about a kind of scene: a paper or extension mean, contrast or
    interaction claim (``spec.instances.takes_instances``) that counts in its family
    (``sequential_study.counts_in_group``) and is not run-to-run."""
    return (claim.group in METHOD_GROUPS and takes_instances(claim) and not run_to_run(study, claim)
            and counts_in_group(study, claim, register))


def claim_spans(study: str, claims: tuple[ClaimSpec, ...], runs: pd.DataFrame | None,
                register: Register) -> list[dict]:
    """One row (``COLUMNS``) per counted method claim of ``study``: ``instances``, the fewest
    instances any of its scenes has among its tested runs (0 when a scene has none, or there
    are no runs); ``most_instances``, the most any of them has; ``per_scene``, each scene's count
    (``studio: 3, exposure_drift: 1``); ``runs``, its finished runs. ``runs``: the study's runs
    frame, with or without instance columns."""
    rows = []
    for c in claims:
        if not method_claim(study, c, register):
            continue
        ran = tested_runs(runs, c, c.scenes) if runs is not None and not runs.empty else pd.DataFrame()
        spanned = instances_spanned(ran) if len(ran) else pd.Series(dtype=int)
        counts = {s: int(spanned.get(s, 0)) for s in c.scenes}
        rows.append({"study": study, "claim": c.id, "group": str(c.group), "scenes": ", ".join(c.scenes),
                     "instances": min(counts.values(), default=0), "most_instances": max(counts.values(), default=0),
                     "per_scene": ", ".join(f"{s}: {k}" for s, k in counts.items()), "runs": len(ran)})
    return rows


def committed_spans(root: Path = COMMITTED_REPORTS, studies_dir: Path | None = None) -> pd.DataFrame:
    """``claim_spans`` of every study's claims on its committed runs (``root/<study>/runs.csv``;
    a study without one: no runs), one frame (``COLUMNS``)."""
    register = load_register(studies_dir)
    rows: list[dict] = []
    for name in list_studies(studies_dir):
        study = load_study(name, studies_dir)
        path = Path(root) / name / "runs.csv"
        runs = pd.read_csv(path, dtype={"git_sha": str, "start_time": str}) if path.is_file() else None
        runs = None if runs is None else add_differences(instance_columns(runs, study))  # as report.families reads it
        rows += claim_spans(name, study.claims, runs, register)
    return pd.DataFrame(rows, columns=COLUMNS)
