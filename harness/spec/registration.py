"""Was a claim registered before its runs? Computed from git, never written by hand.

A claim's **registration commit** is the most recent commit that changed what the claim tests:
its registration fingerprint (``claim_fingerprint``) — its text, metric, test, expectation, arms
(``a``, ``b``, ``contrasts``, ``pairs``, ``among``), scenes, pairing, ``versus``, group,
``requires`` and a mean claim's sequential plan (its ``plan:`` and every profile's
``sequential:`` block, both left out while absent, so no fingerprint of a claim without one
changed when they were added); the definitions of its arms (their override lists in the study's
``variants:`` and in the quick profile's ``variants:``); and the definitions of its scenes in the
quick profile (generator arguments, overrides, rungs and the ladders those set, and, for a
claim that takes instances — a mean, contrast or interaction claim without ``unit: seed``
(``spec.instances.takes_instances``) — ``instances`` when not 1: the count for a fixed-n claim
(its n), only that it is more than 1 for a claim run until decided (its registered cap, not the
count drawn, bounds what it reads)). Any other claim reads the scenes as written only, so
instances drawn of its scenes, or ``unit: seed`` written on it, change nothing of it. A key left out
counts as its default, so writing a default out changes nothing; a claim without ``scenes`` or ``among`` meant
every scene or variant of the quick profile at that version, so a scene added there widened it.
``history:`` notes, ``withdrawn:`` and comments are not part of it.

Its **role commit** is the most recent commit that changed its place in the paper register
(``studies/_paper.yaml``): which statement it decides, is evidence for or was replaced in, and
which claim decides that statement. A claim outside the register has none.

Both are found by walking ``git log`` of the files they are read from (``studies/<study>.yaml``
and ``studies/_scene_sets.yaml``; ``studies/_paper.yaml``) and parsing each version's YAML as raw
data (an old version need not validate against today's schema): the newest commit whose version
gives another fingerprint than its first parent's. A working tree whose version gives another
fingerprint than ``HEAD``'s is "not committed", registered after anything.

``registration(...)`` then answers "registered before its runs?": ``yes`` when both commits are
ancestors of (or equal to) the commit of the earliest run the claim's test reads (once fresh
scene instances ran, not the pilot instance 0's: ``spec.instances``) (``git merge-base
--is-ancestor``; the runs' ``git_sha`` column, ``start_time`` for the order), ``no`` when one is
not, ``unknown`` when git cannot say (no repository, a shallow clone, runs without a recorded
commit or one this clone lacks) — said plainly, never guessed. A run made from a dirty tree
(``<sha>-dirty``) is judged by its commit and the answer says "runs from uncommitted code".

The walk follows ``git log``'s default history simplification, so an edit made on a merged
branch counts from the commit that made it (a merge that takes a file as one parent had it is
not listed); a listed commit is compared with its first parent. Every ``git`` call is cached per
repository (one process decides every claim of every study): file versions are read through one
``git cat-file --batch`` process.

    from harness.spec.registration import registrations
    registrations("secret5", study.claims, runs_df)   # {claim id: Registration}
"""

from __future__ import annotations

import dataclasses
import functools
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable

import pandas as pd
import yaml

from harness.spec import git_repo
from harness.spec.git_repo import repository
from harness.spec.instances import INSTANCE_TESTS, on_scenes, tested
from harness.spec.study_schema import ClaimSpec

YES, NO, UNKNOWN = "yes", "no", "unknown"
NOT_COMMITTED = "not committed"
REGISTER_FILE = "_paper.yaml"
SCENE_SETS_FILE = "_scene_sets.yaml"
# the keys of a claim that register it, with the value an absent key means (ClaimSpec's defaults,
# as written in a file); scenes and among (None) default to the quick profile's (claim_fingerprint)
CLAIM_KEYS = {"claim": "", "metric": "", "test": "", "expect": "", "a": "", "b": "", "scenes": None, "pair": "seed",
              "versus": "", "group": "paper", "contrasts": [], "pairs": [], "among": None, "requires": []}
# keys added after claims were registered: in the fingerprint only when set, so that adding them
# to the schema changed no fingerprint (a plan, ``{}`` or keys set to null count as absent)
LATER_KEYS = ("plan",)
SCENE_KEYS = ("synth", "overrides", "rungs")  # what a scene of the quick profile is made of
UNIT_DEFAULT = "instance"  # ClaimSpec.unit when left out
MISSING = object()  # a file absent at a version


@dataclass(frozen=True)
class Registration:
    """Where a claim's registration and role come from, and whether both precede its runs."""

    claim_commit: str = ""  # a sha, NOT_COMMITTED, or "" (git cannot say)
    role_commit: str = ""  # a sha, NOT_COMMITTED, or "" (outside the register, or git cannot say)
    first_run_commit: str = ""  # the earliest run's commit as recorded (``-dirty`` kept), "" unknown
    before_runs: str = UNKNOWN  # YES | NO | UNKNOWN
    why: str = ""  # one clause: what decided the answer


def forget() -> None:
    """Drop every cached answer (a test that commits, or a process whose checkout moved on)."""
    git_repo.forget()
    _HISTORIES.clear()


# --------------------------------------------------------------------------- fingerprints


@functools.lru_cache(maxsize=4096)
def _parsed(blob: bytes | None) -> Any:
    """A file's YAML as plain data; MISSING when absent; the text itself when it does not parse."""
    if blob is None:
        return MISSING
    try:
        return yaml.safe_load(blob.decode())
    except (yaml.YAMLError, UnicodeDecodeError):
        return blob.decode(errors="replace")


def _canonical(value: Any) -> Any:
    """Plain data with numbers as floats (1 and 1.0 are one weight) and text whitespace-normalised."""
    if isinstance(value, bool) or value is None:
        return value
    if isinstance(value, (int, float)):
        return float(value)
    if isinstance(value, str):
        return " ".join(value.split())
    if isinstance(value, dict):
        return {str(k): _canonical(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_canonical(v) for v in value]
    return str(value)


def _quick(study: dict, sets: Any) -> tuple[dict, list[dict]]:
    """The quick profile (raw) and its scenes, a scene-set name resolved in ``_scene_sets.yaml``."""
    profiles = study.get("profiles") if isinstance(study.get("profiles"), dict) else {}
    quick = profiles.get("quick") if isinstance(profiles.get("quick"), dict) else {}
    scenes = quick.get("scenes", [])
    if isinstance(scenes, str):
        scenes = sets.get(scenes, []) if isinstance(sets, dict) else []
    return quick, [s for s in scenes or [] if isinstance(s, dict)]


def _claim(study: Any, claim_id: str) -> dict | None:
    if not isinstance(study, dict) or not isinstance(study.get("claims"), list):
        return None
    return next((c for c in study["claims"] if isinstance(c, dict) and c.get("id") == claim_id), None)


def _arms(claim: dict) -> list[str]:
    """Every variant the raw claim names (as ``ClaimSpec.arms``), in order of first mention."""
    named = [claim.get("a"), claim.get("b")]
    for weights in claim.get("contrasts") or []:
        named += list(weights) if isinstance(weights, dict) else []
    for pair in claim.get("pairs") or []:
        named += list(pair) if isinstance(pair, (list, tuple)) else []
    named += list(claim.get("among") or [])
    return list(dict.fromkeys(str(v) for v in named if v))


def _set(value: Any) -> Any:
    """A mapping without its keys set to null (they count as absent); any other value as it is."""
    return {k: v for k, v in value.items() if v is not None} if isinstance(value, dict) else value


def claim_fingerprint(study: Any, sets: Any, claim_id: str) -> str | None:
    """Canonical JSON of what registers ``claim_id`` in one version of a study file (raw YAML) and
    of the scene sets; None when the version has no such claim (module docstring)."""
    claim = _claim(study, claim_id)
    if claim is None:
        return None
    quick, scenes = _quick(study, sets)
    study_variants = study.get("variants") if isinstance(study.get("variants"), dict) else {}
    quick_variants = quick.get("variants") if isinstance(quick.get("variants"), dict) else None
    body = {k: claim.get(k, default) for k, default in CLAIM_KEYS.items()}
    if not body["scenes"]:  # the old default: every scene of the quick profile
        body["scenes"] = [s.get("name") for s in scenes]
    if not body["among"] and body["test"] in ("decoupled", "dissociated"):  # every variant it ran
        body["among"] = list(quick_variants if quick_variants is not None else study_variants)
    body = {**body, "among": body["among"] or []}
    for k in LATER_KEYS:
        value = _set(claim.get(k))
        body.update({k: value} if value else {})
    profiles = study.get("profiles") if isinstance(study.get("profiles"), dict) else {}
    sequential = {str(n): _set(p.get("sequential")) for n, p in profiles.items()
                  if body["test"] == "mean" and isinstance(p, dict) and _set(p.get("sequential"))}
    takes = body["test"] in INSTANCE_TESTS and claim.get("unit") in (None, UNIT_DEFAULT)  # spec.instances
    by_name = {s.get("name"): s for s in scenes}
    ladders = quick.get("ladders") if isinstance(quick.get("ladders"), dict) else {}
    scene_defs = {}
    for name in body["scenes"] or []:
        scene = by_name.get(name, {})
        rungs = scene.get("rungs") if isinstance(scene.get("rungs"), dict) else {}
        # fresh instances change the test of a claim that takes them (the instance becomes its unit,
        # the pilot is left out); their count is a fixed-n claim's n, while a claim run until decided
        # reads its first n up to its registered cap, whatever the count drawn (instance i is the same
        # draw for any count). A claim that does not take them reads the pilot only: nothing changes
        count = scene.get("instances")
        several = ({"instances": "several" if sequential else count}
                   if count not in (None, 1) and takes else {})
        scene_defs[str(name)] = {**{k: scene.get(k) for k in SCENE_KEYS},
                                 "ladders": {str(lad): ladders.get(lad) for lad in rungs}, **several}
    arms = {v: {"study": study_variants.get(v), "quick": None if quick_variants is None else quick_variants.get(v)}
            for v in _arms(body)}
    return json.dumps(_canonical({"claim": body, "arms": arms, "scenes": scene_defs}
                                 | ({"sequential": sequential} if sequential else {})), sort_keys=True,
                      ensure_ascii=False)


def role_fingerprint(register: Any, ref: str) -> str | None:
    """Canonical JSON of ``study.claim``'s place in one version of the register (raw YAML): the
    statement, the role and the claim that decides it; None when the register does not name it."""
    statements = register.get("statements") if isinstance(register, dict) else None
    for s in statements if isinstance(statements, list) else []:
        if not isinstance(s, dict):
            continue
        for role, key in (("decides", "decided_by"), ("evidence", "evidence"), ("replaced", "replaced")):
            value = s.get(key)
            names = [value] if isinstance(value, str) else list(value or []) if isinstance(value, list) else []
            if ref in names:
                return json.dumps({"statement": s.get("id"), "role": role, "decided_by": s.get("decided_by")},
                                  sort_keys=True)
    return None


# --------------------------------------------------------------------------- walking the history


class History:
    """The registration and role commits of every claim of the study files under one folder."""

    def __init__(self, studies_dir: Path):
        self.dir = Path(studies_dir).resolve()
        self.repo = repository(self.dir)
        self.problem = ""
        if self.repo is None:
            self.problem = "the studies are not in a git checkout with history"
        elif self.repo.shallow:
            self.problem = "a shallow clone: the history that registered the claims is not here"
        self._rel = self.dir.relative_to(self.repo.root.resolve()).as_posix() if self.repo else ""

    def _path(self, name: str) -> str:
        return f"{self._rel}/{name}" if self._rel not in ("", ".") else name

    def _at(self, commit: str | None, name: str) -> Any:
        """The raw YAML of ``studies/name`` at ``commit`` (None: the working tree)."""
        if commit is None:
            path = self.dir / name
            return _parsed(path.read_bytes() if path.is_file() else None)
        assert self.repo is not None
        return _parsed(self.repo.show(commit, self._path(name)))

    def _walk(self, names: tuple[str, ...], fingerprint: Any) -> str:
        """The newest commit whose version of ``names`` gives another ``fingerprint`` than its first
        parent's; NOT_COMMITTED when the working tree's differs from HEAD's; "" when never present."""
        assert self.repo is not None
        if fingerprint(None) != fingerprint(self.repo.head):
            return NOT_COMMITTED
        for commit, parent in self.repo.log(tuple(self._path(n) for n in names)):
            mine = fingerprint(commit)
            if mine is None:
                return ""  # absent since this commit: nothing here registers it
            if not parent or mine != fingerprint(parent):
                return commit
        return ""

    def claim_commit(self, study: str, claim_id: str) -> str:
        """The claim's registration commit (module docstring); "" when git cannot say."""
        if self.problem:
            return ""
        file = f"{study}.yaml"
        return self._walk((file, SCENE_SETS_FILE), lambda c: claim_fingerprint(
            self._at(c, file), self._at(c, SCENE_SETS_FILE), claim_id))

    def role_commit(self, study: str, claim_id: str) -> str:
        """The commit that last changed the claim's place in the register; "" outside it or when git cannot say."""
        if self.problem:
            return ""
        ref = f"{study}.{claim_id}"
        if role_fingerprint(self._at(None, REGISTER_FILE), ref) is None:
            return ""
        return self._walk((REGISTER_FILE,), lambda c: role_fingerprint(self._at(c, REGISTER_FILE), ref))


_HISTORIES: dict[Path, History] = {}


def history(studies_dir: Path) -> History:
    """One ``History`` per folder and process (until ``forget``)."""
    folder = Path(studies_dir).resolve()
    if folder not in _HISTORIES:
        _HISTORIES[folder] = History(folder)
    return _HISTORIES[folder]


# --------------------------------------------------------------------------- before the runs?


def earliest_commit(runs: pd.DataFrame) -> tuple[str, str]:
    """(the commit of the earliest of ``runs``, "") or ("", why not): by ``start_time`` when every
    run has one, else the one commit they all share."""
    if "git_sha" not in runs:
        return "", "its runs record no commit (a runs.csv written before the git_sha column)"
    shas = runs.git_sha.astype(object).fillna("").astype(str).str.strip()
    if (shas.isin(["", "unknown", "nan"])).any():
        return "", "some of its runs record no commit"
    times = runs.start_time.astype(object).fillna("").astype(str) if "start_time" in runs else None
    if times is not None and not times.isin(["", "nan"]).any():
        return str(shas[times.sort_values(kind="stable").index[0]]), ""
    if shas.nunique() == 1:
        return str(shas.iloc[0]), ""
    return "", "its runs come from several commits and record no start times"


def _claim_runs(claim: ClaimSpec, runs: pd.DataFrame) -> pd.DataFrame:
    """The finished runs a claim is tested on: its arms on its scenes (every instance of each, the
    pilot instance 0 left out once fresh instances ran: ``spec.instances.tested``)."""
    if runs.empty or "status" not in runs:
        return runs.iloc[0:0]
    runs = tested(runs, claim)  # on every row, planned ones too (spec.instances.fresh)
    ok = runs[runs.status == "FINISHED"]
    arms = claim.arms()
    if arms:
        ok = ok[ok.variant.isin(arms)]
    return ok[on_scenes(ok, claim.scenes)] if claim.scenes else ok


def _short(commit: str) -> str:
    return commit if commit in ("", NOT_COMMITTED) else commit[:12]


def registration(study: str, claim: ClaimSpec, runs: pd.DataFrame, studies_dir: Path) -> Registration:
    """Was ``claim`` registered (and given its place in the register) before its earliest run?"""
    hist = history(Path(studies_dir).resolve())
    ran = _claim_runs(claim, runs)
    first, no_first = earliest_commit(ran) if len(ran) else ("", "no finished runs of it")
    found = Registration(first_run_commit=first)
    if hist.problem:
        return dataclasses.replace(found, why=hist.problem)
    reg, role = hist.claim_commit(study, claim.id), hist.role_commit(study, claim.id)
    found = dataclasses.replace(found, claim_commit=reg, role_commit=role)
    late = [what for what, c in (("the claim", reg), ("its place in the paper register", role)) if c == NOT_COMMITTED]
    if not len(ran):
        return dataclasses.replace(found, why=no_first)
    if late:
        return dataclasses.replace(found, before_runs=NO, why=f"{' and '.join(late)} changed after the last commit")
    if not reg:
        return dataclasses.replace(found, why="no commit of its study file holds the claim")
    if not first:
        return dataclasses.replace(found, why=no_first)
    run = first.removesuffix("-dirty")
    dirty = "; runs from uncommitted code" if first.endswith("-dirty") else ""
    assert hist.repo is not None
    verdicts = [(what, c, hist.repo.is_ancestor(c, run)) for what, c in (("claim", reg), ("role", role)) if c]
    if any(ok is None for _, _, ok in verdicts):
        return dataclasses.replace(found, why=f"commit {_short(run)} of its first run is not in this clone{dirty}")
    after = [f"its {what} at {_short(c)}" for what, c, ok in verdicts if not ok]
    if after:
        return dataclasses.replace(found, before_runs=NO,
                                   why=f"{' and '.join(after)} came after its first run's commit {_short(run)}{dirty}")
    return dataclasses.replace(found, before_runs=YES,
                               why=f"registered at {_short(reg)}, first run at {_short(run)}{dirty}")


def registrations(study: str, claims: Iterable[ClaimSpec], runs: pd.DataFrame,
                  studies_dir: Path) -> dict[str, Registration]:
    """``registration`` of every claim of one study, by claim id."""
    return {c.id: registration(study, c, runs, studies_dir) for c in claims}
