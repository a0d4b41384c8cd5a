"""The register of the paper's statements (``studies/_paper.yaml``): one entry per statement.

Each entry paraphrases one statement of the paper (never its prose), says where the paper makes
it (section, table), gives the paper's numbers per dataset with the spread the paper reports
*for that configuration* (or none), and names how our runs decide it:

- ``decided_by``: the one claim (``study.claim``) whose test decides the statement's row in the
  index — one counted row per statement;
- ``evidence``: other conditions of the same statement (another scene, a larger budget),
  evaluated and shown inside the row but not counted and not in the family's correction;
- ``replaced``: claims that decided the statement before and were withdrawn (their study file
  says why); their results stay in view;
- ``rule``: why ``decided_by`` decides and when that rule was fixed (before or after the runs);
- ``not_tested``: what the statement needs when nothing here decides it (real data, a method
  this project does not have, a measure it does not take).

``load_register(studies_dir)`` reads and checks the file (one ``InputError`` naming the key);
``check_register(register, studies)`` checks it against the study files: every claim it names
exists with the right group, a replaced claim is withdrawn and a deciding one is not, and every
``paper``/``convention`` claim of every study belongs to exactly one statement.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from ftgspp.errors import InputError
from harness.spec.structured import read
from harness.spec.study_schema import ClaimGroup, ClaimSpec, StudySpec

REGISTER_FILE = "_paper.yaml"


@dataclass(frozen=True)
class PaperRow:
    """What the paper reports for one dataset: the compared values, their spread and runs.

    ``a`` and ``b`` are the paper's values of the statement's two sides (``b`` None: ``a`` is
    the effect itself); ``a_std``/``b_std`` with ``n`` runs per arm where the paper reports a
    spread *for this configuration* — a spread borrowed from another table is not one.
    ``scene``: our synthetic scene that stands in for the dataset; ``note``: what a number means
    when it is not a plain a/b (a ratio of SDs, a gap between two strides ...).
    """

    dataset: str
    a: float | None = None
    b: float | None = None
    a_std: float | None = None
    b_std: float | None = None
    n: int | None = None
    scene: str = ""
    note: str = ""

    @property
    def effect(self) -> float | None:
        """The paper's effect a − b (or a), None when it gives no number."""
        if self.a is None:
            return None
        return self.a - (self.b or 0.0)


@dataclass(frozen=True)
class Statement:
    """One statement of the paper (paraphrased), where it is made, its numbers and what decides it."""

    id: str
    part: str  # the part of the paper: "secret 1" ... "secret 5", "ablation", "outdoor", "conventions", ...
    statement: str
    source: str  # section / table of the paper (or its supplement)
    family: ClaimGroup = ClaimGroup.paper
    numbers: tuple[PaperRow, ...] = ()
    decided_by: str = ""  # "study.claim"
    evidence: tuple[str, ...] = ()
    replaced: tuple[str, ...] = ()
    rule: str = ""
    not_tested: str = ""

    def claims(self) -> tuple[str, ...]:
        """Every claim the statement names, deciding first."""
        return tuple(c for c in (self.decided_by, *self.evidence, *self.replaced) if c)


@dataclass(frozen=True)
class Register:
    statements: tuple[Statement, ...] = ()

    def role(self, study: str, claim: str) -> tuple[Statement, str] | None:
        """(statement, "decides" | "evidence" | "replaced") of ``study.claim``, or None."""
        ref = f"{study}.{claim}"
        for s in self.statements:
            if s.decided_by == ref:
                return s, "decides"
            if ref in s.evidence:
                return s, "evidence"
            if ref in s.replaced:
                return s, "replaced"
        return None


def _checked(statement: Statement, where: str) -> Statement:
    at = f"{where}.{statement.id}"
    if bool(statement.decided_by) == bool(statement.not_tested):
        raise InputError(at, "give either decided_by (a claim) or not_tested (what it needs), not both")
    if statement.evidence and not statement.decided_by:
        raise InputError(f"{at}.evidence", "evidence needs a deciding claim (decided_by)")
    for ref in statement.claims():
        if ref.count(".") != 1:
            raise InputError(at, f"'{ref}' must name a claim as study.claim")
    for r in statement.numbers:
        if r.n is not None and r.n < 2:
            raise InputError(f"{at}.numbers.{r.dataset}.n", "needs at least 2 runs")
        if (r.a_std is None) != (r.b_std is None) and r.b is not None:
            raise InputError(f"{at}.numbers.{r.dataset}", "give both a_std and b_std, or neither")
    return dataclasses.replace(statement, statement=" ".join(statement.statement.split()),
                               rule=" ".join(statement.rule.split()), not_tested=" ".join(statement.not_tested.split()))


def load_register(studies_dir: Path) -> Register:
    """``studies_dir/_paper.yaml`` read and checked on its own (an empty register when absent)."""
    path = Path(studies_dir) / REGISTER_FILE
    if not path.is_file():
        return Register()
    try:
        raw: Any = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise InputError(path, f"not valid YAML ({str(exc).splitlines()[0]})") from None
    register = read(raw, Register, str(path))
    ids = [s.id for s in register.statements]
    if len(set(ids)) != len(ids):
        raise InputError(f"{path}: statements", "statement ids must be unique")
    return Register(tuple(_checked(s, f"{path}: statements") for s in register.statements))


def check_register(register: Register, studies: dict[str, StudySpec], where: str) -> None:
    """The register against the study files (module docstring); one ``InputError`` at the first problem."""
    claims: dict[str, ClaimSpec] = {f"{n}.{c.id}": c for n, s in studies.items() for c in s.claims}
    seen: dict[str, str] = {}
    for s in register.statements:
        for ref in s.claims():
            at = f"{where}: statements.{s.id}"
            if ref not in claims:
                raise InputError(at, f"no claim '{ref}' in the study files")
            if ref in seen:
                raise InputError(at, f"'{ref}' already belongs to statement {seen[ref]}")
            seen[ref] = s.id
            c = claims[ref]
            if c.group != s.family:
                raise InputError(at, f"'{ref}' is in group {c.group}, the statement in family {s.family}")
            if (ref in s.replaced) != bool(c.withdrawn):
                raise InputError(at, f"'{ref}' is {'not ' if not c.withdrawn else ''}withdrawn in its study file"
                                     f" but {'listed' if ref in s.replaced else 'not listed'} as replaced")
    unregistered = (ClaimGroup.extension, ClaimGroup.second_method)  # claims of this project, not the paper's
    orphans = [ref for ref, c in claims.items() if c.group not in unregistered and ref not in seen]
    if orphans:
        raise InputError(f"{where}: statements", f"claims of the paper or a convention with no statement: "
                                                 f"{', '.join(orphans)}")
