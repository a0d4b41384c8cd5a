"""A claim's scope (scenes and arms) is fixed when it is registered.

When ``long_slow`` joined secret 4 for the haze claim, two claims that named no scenes silently
began pooling it. Now every claim names its scenes and arms (the loader refuses one that does
not), and this test adds a scene and an arm to a copy of every study file and checks that every
existing claim is tested on exactly the same runs, with the same result, as before.
"""

from __future__ import annotations

import copy
import hashlib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from ftgspp.errors import InputError
from harness.analysis import verdicts
from harness.spec.runs import Selection, expand
from harness.spec.study_files import STUDIES_DIR, list_studies, parse_study

PROBE_ARM, PROBE_SCENE = "scope_probe_arm", "scope_probe_scene"


def _raw(name: str) -> dict:
    return yaml.safe_load((STUDIES_DIR / f"{name}.yaml").read_text())


def _sets() -> dict:
    return yaml.safe_load((STUDIES_DIR / "_scene_sets.yaml").read_text()) or {}


def _widened(raw: dict) -> dict:
    """The study file with one more variant (run on every scene) and one more quick scene."""
    out = copy.deepcopy(raw)
    out["variants"][PROBE_ARM] = ["seed=0"]
    quick = out["profiles"]["quick"]
    if quick.get("variants"):
        quick["variants"][PROBE_ARM] = ["seed=0"]
    scenes = quick["scenes"] if isinstance(quick["scenes"], list) else _sets()[quick["scenes"]]
    probe = {k: v for k, v in copy.deepcopy(scenes[0]).items() if k not in ("variants", "rungs", "label", "instances")}
    quick["scenes"] = [*scenes, {**probe, "name": PROBE_SCENE}]
    for s in quick["scenes"]:
        if s.get("variants"):
            s["variants"] = [*s["variants"], PROBE_ARM]
    return out


def _metrics(study) -> list[str]:
    names = set()
    for c in study.claims:
        names |= {c.metric, c.versus, *(r.metric for r in c.requires), *(r.above for r in c.requires)}
    return sorted(n for n in names if n and not n.replace(".", "").isdigit())


def _frame(study) -> pd.DataFrame:
    """Finished runs of the quick profile with a reproducible random value per (run, metric)."""
    rows = []
    for run in expand(study, Selection(profile="quick")):
        row = {"variant": run.variant, "scene": run.scene.name, "seed": run.seed, "status": "FINISHED"}
        for m in _metrics(study):
            digest = hashlib.sha256(f"{run.variant}/{run.scene.name}/{run.seed}/{m}".encode()).digest()
            row[m] = float(np.random.default_rng(int.from_bytes(digest[:8], "little")).normal(1000.0, 1.0))
        rows.append(row)
    return pd.DataFrame(rows)


@pytest.mark.parametrize("name", list_studies())
def test_adding_a_scene_and_an_arm_leaves_every_claim_as_it_was(name):
    path = STUDIES_DIR / f"{name}.yaml"
    before = parse_study(_raw(name), path, _sets())
    after = parse_study(_widened(_raw(name)), path, _sets())
    wide = _frame(after)
    assert PROBE_SCENE in set(wide.scene) and PROBE_ARM in set(wide.variant)
    narrow = wide[(wide.scene != PROBE_SCENE) & (wide.variant != PROBE_ARM)]
    assert len(narrow) == len(_frame(before))
    cols = ["id", "scope", "n", "effect", "ci_low", "ci_high", "p", "p_tost", "verdict", "note"]
    got = verdicts.evaluate(wide, after.claims)[cols]
    want = verdicts.evaluate(narrow, before.claims)[cols]
    pd.testing.assert_frame_equal(got.reset_index(drop=True), want.reset_index(drop=True))
    assert not got.scope.str.contains(PROBE_SCENE).any()


def _claim_file(tmp_path: Path, claim: dict) -> Path:
    raw = {"name": "scoped", "question": "q", "baseline": "a", "variants": {"a": [], "b": ["seed=1"]},
           "profiles": {"quick": {"scenes": [{"name": "s1", "synth": {"preset": "studio"}}]},
                        "paper": {"scenes": [{"name": "s1", "synth": {"preset": "studio"}}]}},
           "claims": [{"id": "c", "group": "extension", "claim": "a beats b", "metric": "psnr", **claim}]}
    path = tmp_path / "scoped.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def test_a_claim_without_scenes_fails_to_load_with_one_line(tmp_path):
    path = _claim_file(tmp_path, {"test": "mean", "a": "a", "b": "b", "expect": "higher"})
    with pytest.raises(InputError, match=r"claims\.c\.scenes: name the claim's scenes") as err:
        parse_study(yaml.safe_load(path.read_text()), path)
    assert "\n" not in str(err.value)


def test_a_claim_naming_an_unknown_scene_fails(tmp_path):
    path = _claim_file(tmp_path, {"test": "mean", "a": "a", "b": "b", "expect": "higher", "scenes": ["nowhere"]})
    with pytest.raises(InputError, match="unknown scene 'nowhere'"):
        parse_study(yaml.safe_load(path.read_text()), path)


def test_an_existential_claim_must_name_the_variants_it_searches(tmp_path):
    path = _claim_file(tmp_path, {"test": "dissociated", "versus": "motion_epe_dynamic", "expect": "exists",
                                  "scenes": ["s1"]})
    with pytest.raises(InputError, match=r"claims\.c\.among: name the variants"):
        parse_study(yaml.safe_load(path.read_text()), path)
