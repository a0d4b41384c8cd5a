"""Scene instances: several synthetic draws of one kind of scene (issue 57; docs/sequential.md).

Seeds on one scene instance are technical replicates; a claim about a method on a kind of scene
needs several instances of it. A profile's scene says how many (``instances: K``, default 1) and
the loader (``spec.study_files``) expands it here into K scenes:

- instance 0 is the scene exactly as written: its name, generator arguments and data folder, so
  every run made before instances existed keeps its run key and config hash;
- instance i ≥ 1 is ``<name>@<i>`` (``instance_name``), drawn with the same generator arguments
  and ``synth.seed`` + 1000 i (``SEED_STRIDE``: two written scenes whose seeds differ by less
  never share a draw, e.g. ``seed: 21`` and ``seed: 23`` of one preset), in its own folder
  (``data/synth/<name>@<i>``), and run at one seed (``FRESH_SEEDS``; ``--seeds`` still wins):
  with the instance as the unit, one more instance buys more than a second seed of one (the
  seeds' noise is only part of an instance mean's variance, the instance's own effect the
  rest). ``@`` cannot appear in a scene name written in a file (``study_files.NAME_PATTERN``),
  so an instance never collides with a written scene, and it is plain text in MLflow tags,
  Hydra override values and folder names;
- each carries ``instance_of`` (the written name, which claims use) and ``instance`` (i); a
  label, when the scene has one, says which instance (``colour shift, instance 2``).

Only a synthetic scene has instances: real data is one recording. ``instance_columns`` gives a
study's runs frame its ``instance_of`` and ``instance`` columns from the study's scene specs (not
from run tags, so runs made before instances, and committed ``runs.csv`` files, get them too).

**Instance 0 is the pilot.** Every claim was written, and its arms explored, on the scene as
written, before instances existed; so a claim with the instance as its unit (``takes_instances``:
a mean, contrast or interaction claim without ``unit: seed``) is tested on the *fresh* instances
1, 2, … of each scene that has any (``tested``), never on instance 0, whatever instance 0's runs
say; a claim with the seed as its unit reads the scenes as written only (a fresh instance has
one run per variant). The rule is fixed in code before any run; "registered before its runs" is judged on the
runs the test reads (``spec.registration``).
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pandas as pd

from ftgspp.errors import InputError
from harness.spec.study_schema import ClaimSpec, Comparison, StudyScene, StudySpec, Unit

SEPARATOR = "@"
COLUMNS = ("instance_of", "instance")
PILOT = 0  # the scene as written: where every claim was explored (module docstring)
FRESH_SEEDS = 1  # seeds of a fresh instance (module docstring)
SEED_STRIDE = 1000  # instance i draws with synth.seed + SEED_STRIDE * i
INSTANCE_TESTS = (Comparison.mean, Comparison.contrast, Comparison.interaction)  # tests that can take instances


def instance_name(base: str, i: int) -> str:
    """``studio`` for instance 0, ``studio@2`` for instance 2."""
    return base if i == 0 else f"{base}{SEPARATOR}{i}"


RANGE = re.compile(r"^(?P<base>.+)@(?P<first>\d+)\.\.(?P<last>\d+)$")  # studio@11..620: instances 11 to 620


def expand_ranges(names: list[str]) -> list[str]:
    """``--scenes`` names with ``<scene>@<first>..<last>`` written out (``studio@2..4``: studio@2,
    studio@3, studio@4); a range that runs backwards is one ``InputError``."""
    out = []
    for name in names:
        m = RANGE.match(name)
        if m is None:
            out.append(name)
            continue
        first, last = int(m["first"]), int(m["last"])
        if last < first:
            raise InputError(f"--scenes {name}", f"instances {first}..{last} run backwards")
        out += [instance_name(m["base"], i) for i in range(first, last + 1)]
    return out


def compact_ranges(names: list[str]) -> list[str]:
    """``names`` with every run of three or more consecutive instances of one scene as a range
    (``expand_ranges`` reverses it); each scene's fresh instances together, in first-seen order."""
    order: dict[tuple[str, str], list[int]] = {}  # ("plain", name) or ("fresh", base) -> instances
    for name in names:
        base, sep, i = name.rpartition(SEPARATOR)
        if sep and i.isdigit() and int(i) > 0:
            order.setdefault(("fresh", base), []).append(int(i))
        else:
            order.setdefault(("plain", name), [])
    out = []
    for (kind, name), found in order.items():
        if kind == "plain":
            out.append(name)
            continue
        found = sorted(set(found))
        runs = [[found[0]]]
        for i in found[1:]:
            (runs[-1].append(i) if i == runs[-1][-1] + 1 else runs.append([i]))
        for run in runs:
            out += [f"{name}{SEPARATOR}{run[0]}..{run[-1]}"] if len(run) >= 3 else [instance_name(name, i) for i in run]
    return out


def expand(scene: StudyScene, where: str) -> list[StudyScene]:
    """A resolved scene (``synth`` with its defaults, ``synth_dir`` set) as its ``instances``
    scenes; one ``InputError`` when a scene of real data asks for more than one."""
    if scene.instances < 1:
        raise InputError(f"{where}.instances", "must be a positive integer")
    if scene.synth is None and scene.instances > 1:
        raise InputError(f"{where}.instances", f"scene '{scene.name}' is real data (no synth:), which has one"
                                               " instance: only a synthetic scene can have instances")
    out = []
    folder = Path(scene.synth_dir)
    for i in range(scene.instances):
        name = instance_name(scene.name, i)
        synth = (scene.synth if i == 0 or scene.synth is None
                 else {**scene.synth, "seed": int(scene.synth["seed"]) + SEED_STRIDE * i})
        synth_dir = scene.synth_dir if i == 0 else (folder.parent / (name + folder.name[len(scene.name):])).as_posix()
        label = scene.label if i == 0 or not scene.label else f"{scene.label}, instance {i}"
        seeds = scene.seeds if i == PILOT else FRESH_SEEDS
        out.append(dataclasses.replace(scene, name=name, synth=synth, synth_dir=synth_dir, label=label, seeds=seeds,
                                       instance_of=scene.name, instance=i))
    return out


def on_scenes(df: pd.DataFrame, scenes: tuple[str, ...] | list[str]) -> pd.Series:
    """Which rows of a runs frame are on ``scenes`` as a study file writes them: the scene itself
    or any instance of it (``instance_of``, when the frame has it)."""
    mask = df.scene.isin(scenes)
    return mask | df.instance_of.isin(scenes) if "instance_of" in df else mask


def scene_instances(study: StudySpec) -> dict[str, tuple[str, int]]:
    """Every scene name of every profile of ``study`` -> (the scene it is an instance of, i)."""
    return {s.name: (s.base, s.instance) for p in study.profiles.values() for s in p.scenes}


def instance_columns(df: pd.DataFrame, study: StudySpec | None) -> pd.DataFrame:
    """``df`` (a runs frame) with ``instance_of`` and ``instance`` from the study's scene specs,
    right after ``scene_label`` (else at the end), as ``report.results.runs_frame`` places them; a
    scene the study no longer defines (or every scene, without a study) is instance 0 of itself."""
    if "scene" not in df:
        return df
    known = scene_instances(study) if study is not None else {}
    pairs = [known.get(str(s), (str(s), 0)) for s in df.scene]
    out = df.drop(columns=[c for c in COLUMNS if c in df])
    at = list(out.columns).index("scene_label") + 1 if "scene_label" in out else len(out.columns)
    for k, (col, dtype) in enumerate(zip(COLUMNS, (object, "int64"))):
        out.insert(at + k, col, pd.Series([p[k] for p in pairs], index=out.index, dtype=dtype))
    return out


def takes_instances(claim: ClaimSpec) -> bool:
    """Does the claim take the instance as its unit once fresh instances ran? A mean, contrast or
    interaction claim (a method's effect on a kind of scene) without ``unit: seed``."""
    return claim.test in INSTANCE_TESTS and claim.unit == Unit.instance


def fresh(runs: pd.DataFrame) -> pd.Series:
    """Which rows are on a fresh instance: every row of a scene drawn once, and no row of the
    pilot (instance 0) of a scene drawn several times. A scene counts as drawn several times when
    any row of ``runs`` — planned and not yet run ones too (a runs frame lists every planned run)
    — is on a fresh instance of it, so what a test leaves out never depends on which runs have
    finished."""
    if "instance_of" not in runs or runs.empty:
        return pd.Series(True, index=runs.index)
    several = runs.groupby("instance_of", sort=False).instance.transform("max") > PILOT
    return ~(several & (runs.instance == PILOT))


def tested(runs: pd.DataFrame, claim: ClaimSpec) -> pd.DataFrame:
    """The rows of ``runs`` (a runs frame: every planned run, any status) the claim's test reads
    (module docstring): for a claim that takes instances, none of the pilot of a scene drawn
    several times (``fresh``); for any other claim (the seed its unit: a spread, a variance, an
    existential search, ``unit: seed``), the scenes as written only — repeated runs of one fixed
    scene, never a fresh instance's single run."""
    if "instance" not in runs:
        return runs
    if not takes_instances(claim):
        return runs[runs.instance == PILOT]
    return runs[fresh(runs)] if (runs.instance > PILOT).any() else runs


def mixed_scenes(claim: ClaimSpec, scenes: list[StudyScene]) -> list[str]:
    """The claim's scenes drawn once when another of its scenes is drawn several times, for a
    claim that takes instances (its units would mix one pilot's seeds with fresh instances):
    ``[]`` when the claim is consistent. ``scenes``: one profile's expanded scenes."""
    if not takes_instances(claim):
        return []
    drawn = {s.base for s in scenes if s.base in claim.scenes and s.instance > PILOT}
    present = {s.base for s in scenes}
    once = [n for n in claim.scenes if n in present and n not in drawn]
    return once if drawn and once else []


def check_claims(claims: tuple[ClaimSpec, ...], profiles: dict, where: str) -> tuple[ClaimSpec, ...]:
    """``claims`` when no claim that takes instances mixes, under some profile, a scene drawn
    several times with one drawn once (``mixed_scenes``); else one ``InputError``."""
    for c in claims:
        for name, prof in profiles.items():
            once = mixed_scenes(c, list(prof.scenes))
            if once and not c.withdrawn:
                raise InputError(f"{where}: claims.{c.id}.scenes", f"profile {name} draws some of its scenes as"
                                 f" several instances but not {', '.join(once)}: its instance-level test would mix a"
                                 " pilot's seeds with fresh instances; give those scenes `instances:` too, or say"
                                 " `unit: seed` (it then reads the scenes as written)")
    return claims
