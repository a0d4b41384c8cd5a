"""Study variants match the official FreeTimeGS++ configurations (docs/design.md §4).

Base and +Flow keep FreeTimeGS's unbounded temporal scale (``max_duration = inf``,
``null`` here); the 1 s bound always comes together with the gate
(``marginal_gating = true, max_duration = 1``). Checked on the composed configs, in every
profile of every study, so a profile-wide override cannot slip the bound back in.
"""

from __future__ import annotations

import pytest

from harness.spec.plan import plan_runs
from harness.spec.runs import Selection, expand
from harness.spec.study_files import list_studies, load_study


def composed(name: str, profile: str) -> dict[str, dict[str, str]]:
    """variant -> flattened params of its first scene's run."""
    planned = plan_runs(expand(load_study(name), Selection(profile=profile, seeds=1)))
    out: dict[str, dict[str, str]] = {}
    for p in planned:
        out.setdefault(p.spec.variant, p.params)
    return out


@pytest.mark.parametrize("profile", ["quick", "paper"])
def test_ablation_rows_are_the_official_configurations(profile: str, monkeypatch: pytest.MonkeyPatch) -> None:
    for root in ("DYNERF_ROOT", "ENERF_OUTDOOR_ROOT", "IMMERSIVE_ROOT"):
        monkeypatch.setenv(root, "/data/n3v")
    rows = composed("ablation", profile)
    expect = {  # variant: (velocity init, gate, max_duration, colour correction)
        "base": ("knn", "false", "null", "false"),
        "flow": ("flow", "false", "null", "false"),
        "flow_gate": ("flow", "true", "1.0", "false"),
        "flow_gate_cc": ("flow", "true", "1.0", "true"),
    }
    got = {v: (p["init.velocity"], p["model.gate"], p["model.max_duration"], p["model.color_correction"])
           for v, p in rows.items()}
    assert got == expect


@pytest.mark.parametrize("name", sorted(list_studies()))
def test_the_gate_always_comes_with_the_one_second_bound(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    for root in ("DYNERF_ROOT", "ENERF_OUTDOOR_ROOT", "IMMERSIVE_ROOT"):
        monkeypatch.setenv(root, "/data/n3v")
    for profile in [p for p in ("quick", "paper") if p in load_study(name).profiles]:  # the ones it has
        for variant, p in composed(name, profile).items():
            if p["model.gate"] == "true":
                assert p["model.max_duration"] == "1.0", f"{name}/{profile}/{variant}: gate without the 1 s bound"
