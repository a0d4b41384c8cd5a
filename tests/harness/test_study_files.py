"""Every study file loads, and every variant of every profile composes against the schema."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from ftgspp.errors import InputError
from harness.spec.plan import plan_runs
from harness.spec.runs import Selection, expand
from harness.spec.study_files import TINY_SYNTH, list_studies, load_study, parse_study

REQUIRED = {"secret1", "secret2", "secret3", "secret4", "secret5", "lpips", "ablation", "speed_accuracy", "stability"}


def test_all_paper_studies_exist() -> None:
    assert REQUIRED <= set(list_studies())


@pytest.mark.parametrize("name", sorted(REQUIRED))
def test_study_composes_in_every_profile(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    for root in ("DYNERF_ROOT", "ENERF_OUTDOOR_ROOT", "IMMERSIVE_ROOT"):
        monkeypatch.setenv(root, "/data/n3v")
    study = load_study(name)
    assert study.question and study.baseline
    assert {"quick", "paper", "smoke"} <= set(study.profiles)
    for prof in study.profiles.values():
        assert prof.baseline in prof.variants
        if prof.name != "smoke":
            assert prof.command.startswith(("study run", "DYNERF_ROOT", "IMMERSIVE_ROOT")) and prof.run_seconds > 0  # an estimate
        # one seed is enough: seeds only change the trailing seed= override
        planned = plan_runs(expand(study, Selection(profile=prof.name, seeds=1)))
        assert len(planned) == sum(len(s.variants or prof.variants) for s in prof.scenes)
        assert len({p.config_hash for p in planned}) == len(planned), "two runs of a study must differ"
        for p in planned:
            assert p.params["profile"] == prof.name
    assert 6 <= study.profiles["paper"].seeds <= 10
    smoke = study.profiles["smoke"]
    assert smoke.seeds == 1
    for scene in smoke.scenes:
        assert scene.synth is not None and scene.synth_dir.endswith("-smoke")
        for k in ("width", "height", "n_frames"):
            assert scene.synth[k] == TINY_SYNTH[k]


def test_quick_profiles_use_synthetic_scenes_only() -> None:
    for name in REQUIRED:
        for scene in load_study(name).profiles["quick"].scenes:
            assert scene.synth is not None, f"{name}: quick scene {scene.name} must be synthetic"


def test_runs_use_seed_base_plus_r_and_put_overrides_in_order() -> None:
    study = load_study("secret5")
    runs = expand(study, Selection(profile="quick", seeds=3, variants=["cc"], overrides=["iterations=7"]))
    assert [r.seed for r in runs] == [study.base_seed + r for r in range(3)]
    o = list(runs[0].overrides)
    assert o[0] == "profile=quick" and o[-1] == f"seed={study.base_seed}"
    assert o.index("model.color_correction=true") < o.index("iterations=7")
    assert "data.path=data/synth/studio" in o


def test_fast_composition_matches_full_hydra_compose() -> None:
    from harness.spec.confighash import flatten_config
    from harness.spec.schema import compose, to_train_config

    study = load_study("stability")
    runs = expand(study, Selection(profile="quick", seeds=1, scenes=["lr_x10"]))
    for run, planned in zip(runs, plan_runs(runs)):
        full = flatten_config(to_train_config(compose(list(run.overrides))))
        assert full == planned.params


def test_unknown_names_are_input_errors() -> None:
    with pytest.raises(InputError, match="unknown study"):
        load_study("secret42")
    study = load_study("secret5")
    with pytest.raises(InputError, match="unknown variant"):
        expand(study, Selection(variants=["nope"]))
    with pytest.raises(InputError, match="unknown scene"):
        expand(study, Selection(scenes=["nope"]))
    with pytest.raises(InputError, match="profiles"):
        expand(study, Selection(profile="huge"))
    with pytest.raises(InputError, match="seeds come from"):
        expand(study, Selection(overrides=["seed=3"]))


def test_bad_override_values_name_the_key(monkeypatch: pytest.MonkeyPatch) -> None:
    study = load_study("secret4")
    for bad, word in (("iterations=many", "iterations"), ("nosuchkey=1", "nosuchkey"), ("model.gate=[1", "model.gate")):
        with pytest.raises(InputError, match=word):
            plan_runs(expand(study, Selection(profile="smoke", overrides=[bad])))
    monkeypatch.delenv("DYNERF_ROOT", raising=False)
    with pytest.raises(InputError, match="DYNERF_ROOT"):
        plan_runs(expand(study, Selection(profile="paper", seeds=1)))


def test_study_file_validation(tmp_path: Path) -> None:
    raw = yaml.safe_load((Path(__file__).parent / "studies" / "toy.yaml").read_text())
    raw["baseline"] = "missing"
    with pytest.raises(InputError, match="baseline"):
        parse_study(raw, tmp_path / "toy.yaml")
    raw = yaml.safe_load((Path(__file__).parent / "studies" / "toy.yaml").read_text())
    raw["plots"] = ["pie"]
    with pytest.raises(InputError, match="unknown plot"):
        parse_study(raw, tmp_path / "toy.yaml")


def _toy() -> dict:
    return yaml.safe_load((Path(__file__).parent / "studies" / "toy.yaml").read_text())


def test_scenes_may_carry_their_own_seeds_variants_and_rungs(tmp_path: Path) -> None:
    raw = _toy()
    quick = raw["profiles"]["quick"]
    base = dict(quick["scenes"][0])
    variants = list(raw["variants"])
    quick["seeds"] = 3
    quick["scenes"] = [
        {**base, "name": "base", "rungs": {"lr_scale": 1, "cameras": 10}},
        {**base, "name": "rung", "seeds": 1, "variants": variants[:1], "rungs": {"lr_scale": 3}},
    ]
    study = parse_study(raw, tmp_path / "toy.yaml")
    runs = expand(study, Selection(profile="quick"))
    keys = {r.key for r in runs}
    assert {k for k in keys if k[1] == "base"} == {(v, "base", s) for v in variants for s in (0, 1, 2)}
    assert {k for k in keys if k[1] == "rung"} == {(variants[0], "rung", 0)}
    assert len(runs) == len(keys) == 3 * len(variants) + 1
    assert dict(study.profile("quick").scenes[1].rungs) == {"lr_scale": 3.0}
    # --seeds sets every scene's count; the smoke profile keeps the variant subsets
    assert {r.key for r in expand(study, Selection(profile="quick", seeds=2)) if r.scene.name == "rung"} == \
        {(variants[0], "rung", 0), (variants[0], "rung", 1)}
    assert {r.variant for r in expand(study, Selection(profile="smoke")) if r.scene.name == "rung"} == {variants[0]}
    with pytest.raises(InputError, match="no run of the study"):  # the rung runs only the first variant
        expand(study, Selection(profile="quick", scenes=["rung"], variants=[variants[1]]))


@pytest.mark.parametrize("bad, match", [({"seeds": 0}, "seeds"), ({"variants": ["nosuch"]}, "nosuch"),
                                        ({"rungs": {"lr": "high"}}, "rungs")])
def test_bad_per_scene_keys_are_input_errors(tmp_path: Path, bad: dict, match: str) -> None:
    raw = _toy()
    raw["profiles"]["quick"]["scenes"][0].update(bad)
    with pytest.raises(InputError, match=match):
        parse_study(raw, tmp_path / "toy.yaml")


def test_a_rung_value_sets_its_override_or_generator_argument_in_one_place(tmp_path: Path) -> None:
    raw = _toy()
    quick = raw["profiles"]["quick"]
    base = dict(quick["scenes"][0])
    quick["ladders"] = {"lr_scale": {"override": "lr.scale", "times": 2.0, "base": 1},
                        "cameras": {"synth": "n_cameras", "base": 10}}
    quick["scenes"] = [{**base, "name": "base", "rungs": {"lr_scale": 1, "cameras": 10}},
                       {**base, "name": "lr3", "rungs": {"lr_scale": 3}},
                       {**base, "name": "cams4", "rungs": {"cameras": 4}}]
    scenes = {s.name: s for s in parse_study(raw, tmp_path / "toy.yaml").profile("quick").scenes}
    assert scenes["base"].overrides == () and "n_cameras" not in scenes["base"].synth  # the base rung sets nothing
    assert scenes["lr3"].overrides == ("lr.scale=6.0",)
    assert scenes["cams4"].synth["n_cameras"] == 4
    quick["scenes"][1]["overrides"] = ["lr.scale=6.0"]  # written twice: refused
    with pytest.raises(InputError, match="'lr.scale' is set by the rung lr_scale: 3"):
        parse_study(raw, tmp_path / "toy.yaml")
    quick["scenes"][1] = {**base, "name": "lr3", "rungs": {"lr_scal": 3}}
    with pytest.raises(InputError, match="unknown ladder 'lr_scal'"):
        parse_study(raw, tmp_path / "toy.yaml")


@pytest.mark.parametrize("change, at, words", [
    (lambda raw: raw["table"].update(layout="pie_chart"), "table.layout",
     "unknown table layout 'pie_chart' (use variants_x_scenes, metrics_x_scenes, variants_x_metrics)"),
    (lambda raw: raw.update(claims=[{"id": "c", "claim": "x", "metric": "psnr", "test": "anova", "expect": "higher",
                                     "a": "cc"}]), "claims[0].test",
     "unknown comparison 'anova' (use mean, variance, interaction, contrast, decoupled, dissociated, spread)"),
    (lambda raw: raw.update(claims=[{"id": "c", "claim": "x", "metric": "psnr", "test": "mean", "expect": "higher",
                                     "a": "cc", "among": ["baseline", "cc"]}]), "claims.c.among",
     "only a decoupled or dissociated claim searches 'among' variants (two or more)"),
    (lambda raw: raw["profiles"].update(huge=raw["profiles"]["quick"]), "profiles.huge",
     "unknown profile 'huge' (use quick, paper, smoke)"),
    (lambda raw: raw["profiles"]["quick"]["overrides"].append({}), "profiles.quick.overrides[1]",
     "must be a string, not a mapping"),
])
def test_a_value_outside_its_type_is_one_line_exit_2(change, at: str, words: str, tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    import harness.spec.study_files
    from harness.cli.study import main

    raw = _toy()
    change(raw)
    (tmp_path / "toy.yaml").write_text(yaml.safe_dump(raw))
    with pytest.raises(InputError) as err:
        load_study("toy", tmp_path)
    assert str(err.value) == f"{tmp_path / 'toy.yaml'}: {at}: {words}"
    monkeypatch.setattr(harness.spec.study_files, "STUDIES_DIR", tmp_path)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        main(["run", "toy"])
    assert exc.value.code == 2
    assert [line for line in capsys.readouterr().err.splitlines() if line.strip()] == [f"error: {err.value}"]
    assert not (tmp_path / "mlflow.db").exists()


def test_the_spec_is_typed_and_frozen(tmp_path: Path) -> None:
    import dataclasses

    from harness.spec.study_schema import ClaimGroup, Plot, TableLayout

    study = parse_study(_toy(), tmp_path / "toy.yaml")
    layout = study.table.layout
    assert layout is TableLayout.variants_x_scenes and layout == "variants_x_scenes" and f"{layout}" == layout.value
    assert study.plots == ("strip", "stability", "speed_accuracy") and all(isinstance(p, Plot) for p in study.plots)
    assert ClaimGroup("paper") is ClaimGroup.paper
    with pytest.raises(dataclasses.FrozenInstanceError):
        study.table.layout = TableLayout.metrics_x_scenes  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        study.profile("quick").scenes[0].seeds = 3  # type: ignore[misc]


def test_quick_learning_rate_ladders_are_multiples_of_the_tuned_rate() -> None:
    # a rung "lr x3" means three times the quick profile's tuned lr.scale: a ladder whose `times`
    # still holds an old tuned rate would put every rung at the wrong learning rate
    quick = Path(__file__).resolve().parents[2] / "conf" / "profile" / "quick.yaml"
    tuned = yaml.safe_load(quick.read_text())["lr"]["scale"]
    seen = 0
    for name in list_studies():
        for ladder in load_study(name).profiles["quick"].ladders.values():
            if ladder.override == "lr.scale":
                assert ladder.times == tuned, f"{name}: lr ladder times {ladder.times}, quick lr.scale {tuned}"
                seen += 1
    assert seen >= 2  # stability and collapse


def test_a_rung_on_an_int_setting_is_written_as_a_whole_number():
    """A keyframe-stride rung is the override ``init.keyframe_stride=5`` (the config's int), a
    learning-rate rung stays a float, and a fractional value for an int setting is refused."""
    from harness.spec.study_files import _override_value

    assert _override_value("init.keyframe_stride", 5.0, "w") == "5"
    assert _override_value("init.candidates_per_frame", 1000.0, "w") == "1000"  # int | None
    assert _override_value("lr.scale", 24.0, "w") == "24.0"
    with pytest.raises(InputError, match="whole number"):
        _override_value("init.keyframe_stride", 2.5, "w")


def test_smoke_runs_score_lpips_only_where_it_is_the_point() -> None:
    # LPIPS took 204 s of a 321-s smoke training on 2 cores: the smoke profile scores none, and the
    # lpips study, whose question it is, keeps both networks in its derived smoke profile too
    def nets(name: str) -> set[str]:  # the flattened config writes lists as JSON
        planned = plan_runs(expand(load_study(name), Selection(profile="smoke", seeds=1)))
        return {p.params["eval_lpips"] for p in planned}

    assert nets("secret5") == {"[]"}
    assert nets("lpips") == {'["alex", "vgg"]'}


def test_a_loaded_study_is_parsed_again_when_its_file_or_the_scene_sets_change(tmp_path: Path) -> None:
    """load_study keeps one parse per version of the file (study index loads each study many times)."""
    import os

    studies = Path(__file__).parents[2] / "studies"
    text = (studies / "secret4.yaml").read_text()
    (tmp_path / "_scene_sets.yaml").write_text((studies / "_scene_sets.yaml").read_text())
    (tmp_path / "mine.yaml").write_text(text.replace("name: secret4", "name: mine"))
    first = load_study("mine", tmp_path)
    assert load_study("mine", tmp_path) is first  # unchanged: the same parse
    os.utime(tmp_path / "_scene_sets.yaml", ns=(2, 2))  # the scene sets changed: parsed again
    assert load_study("mine", tmp_path) is not first
    first = load_study("mine", tmp_path)
    (tmp_path / "mine.yaml").write_text(text.replace("name: secret4", "name: mine").replace("seeds: 5", "seeds: 4"))
    os.utime(tmp_path / "mine.yaml", ns=(1, 1))  # a new version even within one clock tick
    second = load_study("mine", tmp_path)
    assert second is not first and second.profiles["quick"].seeds == 4 and first.profiles["quick"].seeds == 5
    (tmp_path / "mine.yaml").write_text("name: mine\nnot: [valid")  # an error is raised on every call
    for _ in range(2):
        with pytest.raises(InputError, match="not valid YAML"):
            load_study("mine", tmp_path)
