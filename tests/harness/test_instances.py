"""Scene instances as the unit of a method claim (issue 57; ``spec.instances``,
``analysis.instance_unit``): a scene's ``instances: K`` expands into K scenes whose instance 0 is
the scene as written (its name, folder, run keys and config hashes, so committed runs stay
valid), a claim naming the scene spans every instance, the runs frame carries ``instance_of`` and
``instance`` from the study file, a mean claim over several instances is tested on per-instance
means (``unit: seed`` keeps the seeds), and over one instance today's test is unchanged."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from fakes import MINI_STUDY

from ftgspp.errors import InputError
from harness.analysis import claim_compare, claim_tests as C, instance_unit as IU, verdicts as V
from harness.analysis.aggregate import KEY_COLUMNS, metric_columns
from harness.report import instance_span
from harness.report.results import runs_frame
from harness.spec import registration
from harness.spec.instances import instance_columns
from harness.spec.paper_register import Register
from harness.spec.plan import plan_runs
from harness.spec.runs import Selection, expand
from harness.spec.study_files import load_study, parse_study
from harness.spec.study_schema import ClaimSpec, StudySpec

ROOT = Path(__file__).resolve().parents[2]


def mini(instances: int = 3, **scene: object) -> dict:
    """MINI_STUDY with ``easy`` (synth seed 4, 2 seeds, both variants) drawn ``instances`` times."""
    raw = copy.deepcopy(MINI_STUDY)
    raw["profiles"]["quick"]["scenes"] = [{"name": "easy", "synth": {"preset": "studio", "seed": 4}, "seeds": 2,
                                           "variants": ["baseline", "cc"], "instances": instances, **scene}]
    return raw


def parsed(name: str, scene: int, k: int) -> StudySpec:
    """The real study ``name`` with its quick scene number ``scene`` drawn ``k`` times."""
    path = ROOT / "studies" / f"{name}.yaml"
    raw = yaml.safe_load(path.read_text())
    raw["profiles"]["quick"]["scenes"][scene]["instances"] = k
    return parse_study(raw, path, yaml.safe_load((ROOT / "studies" / "_scene_sets.yaml").read_text()))


# --------------------------------------------------------------------------- expansion


def test_a_scene_with_instances_expands_into_named_draws_with_their_own_seed_and_folder() -> None:
    study = parse_study(mini(3), Path("mini.yaml"))
    quick = study.profiles["quick"]
    assert [s.name for s in quick.scenes] == ["easy", "easy@1", "easy@2"]
    assert [s.synth["seed"] for s in quick.scenes] == [4, 1004, 2004]
    assert [s.synth_dir for s in quick.scenes] == ["data/synth/easy", "data/synth/easy@1", "data/synth/easy@2"]
    assert [(s.instance_of, s.instance) for s in quick.scenes] == [("easy", 0), ("easy", 1), ("easy", 2)]
    # the rest of the generator arguments and the variants: the same for every instance
    assert all({**s.synth, "seed": 4} == quick.scenes[0].synth for s in quick.scenes)
    assert all(s.variants == ("baseline", "cc") for s in quick.scenes)
    assert [s.seeds for s in quick.scenes] == [2, 1, 1]  # a fresh instance runs one seed (FRESH_SEEDS)
    smoke = study.profiles["smoke"]  # derived from quick: the same instances, tiny and in their own folders
    assert [(s.name, s.synth["seed"], s.synth_dir) for s in smoke.scenes] == [
        ("easy", 4, "data/synth/easy-smoke"), ("easy@1", 1004, "data/synth/easy@1-smoke"),
        ("easy@2", 2004, "data/synth/easy@2-smoke")]
    assert [s.instance_of for s in smoke.scenes] == ["easy"] * 3
    # instance 0 is the scene exactly as written without `instances`
    plain = parse_study(mini(1), Path("mini.yaml")).profiles["quick"].scenes
    assert len(plain) == 1 and plain[0].synth == quick.scenes[0].synth and plain[0].synth_dir == "data/synth/easy"
    # `study run` runs every instance; `--scenes` names them as planned (`easy` is instance 0)
    assert {r.scene.name for r in expand(study, Selection())} == {"easy", "easy@1", "easy@2"}
    assert {r.scene.name for r in expand(study, Selection(scenes=["easy@2"]))} == {"easy@2"}


def test_a_real_data_scene_with_instances_is_one_error_line() -> None:
    raw = copy.deepcopy(MINI_STUDY)
    raw["profiles"]["paper"]["scenes"][0]["instances"] = 2
    with pytest.raises(InputError) as err:
        parse_study(raw, Path("mini.yaml"))
    text = str(err.value)
    assert "\n" not in text and "profiles.paper.scenes[0].instances" in text and "real data" in text
    with pytest.raises(InputError, match="instances.*positive"):
        parse_study(mini(0), Path("mini.yaml"))


def test_claims_name_the_scene_as_written_not_an_instance() -> None:
    raw = mini(3)
    raw["claims"] = [dict(raw["claims"][0], scenes=["easy@1"])]
    with pytest.raises(InputError, match="unknown scene 'easy@1'"):
        parse_study(raw, Path("mini.yaml"))


def test_instance_zero_keeps_the_config_hash_and_the_committed_runs_stay_valid() -> None:
    # ablation's studio drawn 3 times: instance 0 plans exactly the runs the file as written plans
    sel = Selection(profile="quick", seeds=1, scenes=["studio"])
    before = {p.key for p in plan_runs(expand(load_study("ablation"), sel))}
    after = plan_runs(expand(parsed("ablation", 0, 3), Selection(profile="quick", seeds=1,
                                                                scenes=["studio", "studio@1", "studio@2"])))
    assert {p.key for p in after if p.instance == 0} == before
    others = [p for p in after if p.instance > 0]
    assert {(p.instance_of, p.spec.scene.name) for p in others} == {("studio", "studio@1"), ("studio", "studio@2")}
    assert {p.params["data.path"] for p in others} == {"data/synth/studio@1", "data/synth/studio@2"}
    assert not {p.config_hash for p in others} & {key[-1] for key in before}
    assert all(p.tags["scene"] == p.spec.scene.name and "instance" not in p.tags for p in after)  # no new tags
    # and against the committed runs themselves (secret5_cc runs portable: its hashes are any machine's)
    committed = pd.read_csv(ROOT / "reports" / "secret5_cc" / "runs.csv", dtype={"config_hash": str})
    have = set(committed[KEY_COLUMNS].astype(str).itertuples(index=False, name=None))
    planned = plan_runs(expand(parsed("secret5_cc", 0, 2), Selection(profile="quick", seeds=1,
                                                                     scenes=["studio", "studio@1"])))
    zero = [tuple(map(str, p.key)) for p in planned if p.instance == 0]
    assert len(zero) == 2 and set(zero) <= have
    assert not {tuple(map(str, p.key)) for p in planned if p.instance} & have


# --------------------------------------------------------------------------- the runs frame


def test_the_runs_frame_carries_instance_columns_from_the_study_file() -> None:
    study = parse_study(mini(2), Path("mini.yaml"))
    planned = plan_runs(expand(study, Selection(profile="quick")))
    df = runs_frame({}, planned)
    assert list(df.columns[list(df.columns).index("scene_label") + 1:][:2]) == ["instance_of", "instance"]
    assert sorted(set(zip(df.scene, df.instance_of, df.instance))) == [("easy", "easy", 0), ("easy@1", "easy", 1)]
    assert not {"instance_of", "instance"} & set(metric_columns(df))  # neither is a metric
    # a runs.csv written before the columns (or a scene left out of the file since) gets them from the study
    old = df.drop(columns=["instance_of", "instance"]).iloc[:4].assign(scene=["easy", "easy@1", "gone", "easy"])
    back = instance_columns(old, study)
    assert list(back.columns) == list(df.columns)
    assert list(zip(back.instance_of, back.instance)) == [("easy", 0), ("easy", 1), ("gone", 0), ("easy", 0)]
    assert back.instance.dtype == np.int64


# --------------------------------------------------------------------------- instance-level tests


def frame(instances: int, seeds: int = 3, scenes: tuple[str, ...] = ("studio",), seed: int = 0) -> pd.DataFrame:
    """Runs of ``baseline`` and ``cc`` on each scene's instances: cc's effect varies by instance."""
    rng = np.random.default_rng(seed)
    rows = []
    for s in scenes:
        for i in range(instances):
            level, effect = rng.normal(30, 1), rng.normal(0.3, 0.4)
            for r in range(seeds):
                noise = rng.normal(0, 0.05)
                for v, shift in (("baseline", 0.0), ("cc", effect)):
                    rows.append({"variant": v, "scene": s if i == 0 else f"{s}@{i}", "instance_of": s,
                                 "instance": i, "seed": r, "status": "FINISHED",
                                 "psnr": level + shift + noise + rng.normal(0, 0.05)})
    return pd.DataFrame(rows)


def claim(**kw: object) -> ClaimSpec:
    base = {"id": "c", "statement": "s", "metric": "psnr", "test": "mean", "expect": "higher", "a": "cc",
            "b": "baseline", "scenes": ("studio",), "sesoi": 0.1}
    return ClaimSpec(**{**base, **kw})


@pytest.mark.parametrize(("pair", "b", "paired", "method"), [
    ("seed", "baseline", True, "paired t over instance means"),
    ("none", "baseline", False, "Welch t over instance means"),
    ("seed", "", True, "one-sample t over instance means")])
def test_a_mean_claim_over_instances_is_the_instance_means_test(pair: str, b: str, paired: bool, method: str) -> None:
    df = frame(5)
    c = claim(pair=pair, b=b)
    res = claim_compare.compare(df, c, c.scenes)
    fresh = df[df.instance > 0]  # instance 0, the scene as written, is the pilot: never tested
    oracle = IU.instance_test(fresh.assign(scene=fresh.instance_of), "psnr", "cc", b or None, 0.1, paired=paired)
    assert res.method == method and res.n == oracle.n and oracle.n in ("4 instances", "4 vs 4 instances")
    assert (res.effect, res.p, res.p_tost, res.ci) == (oracle.effect, oracle.p, oracle.p_tost, oracle.ci)
    # the oracle itself is the claim's test on the per-instance means, computed here independently
    means = fresh.groupby(["variant", "instance"]).psnr.mean().unstack("variant")
    expected = C.compare_means(means.cc.to_numpy(), None if not b else means[b].to_numpy(), paired, 0.1)
    assert res.p == pytest.approx(expected.p, rel=1e-12) and res.effect == pytest.approx(expected.effect)
    row = V.evaluate(df, [c]).iloc[0]
    assert row.unit == "4 instances, pilot instance 0 left out" and row.n.endswith("instances")


def test_the_pilot_instance_never_enters_an_instance_level_test() -> None:
    """Whatever instance 0 (where the claim was explored) says, the test reads the fresh instances only."""
    df = frame(5)
    wild = df.assign(psnr=df.psnr.where(~((df.instance == 0) & (df.variant == "cc")), 99.0))
    for c in (claim(), claim(pair="none"), claim(b="")):
        one, other = claim_compare.compare(df, c, c.scenes), claim_compare.compare(wild, c, c.scenes)
        assert (one.effect, one.p, one.p_tost, one.n) == (other.effect, other.p, other.p_tost, other.n)
    # without a fresh instance the pilot's seeds are all there is: today's test over seeds
    only_pilot = frame(1, seeds=4)
    assert claim_compare.compare(only_pilot, claim(), ("studio",)).n == "4 pairs"
    # one fresh instance: the instance is the unit, and one is too few to test
    with pytest.raises(ValueError, match="1 instances"):
        claim_compare.compare(frame(2), claim(), ("studio",))


def test_contrast_and_interaction_claims_take_fresh_instances_as_their_unit() -> None:
    df = frame(6, scenes=("studio", "drift"), seed=5)
    contrast = claim(test="contrast", contrasts=((("cc", 1.0), ("baseline", -1.0)),), a="", b="", scenes=("studio",))
    res = claim_compare.compare(df, contrast, contrast.scenes)
    fresh = df[(df.instance > 0) & (df.instance_of == "studio")]
    means = fresh.groupby(["variant", "instance"]).psnr.mean().unstack("variant")
    expected = C.compare_means((means.cc - means.baseline).to_numpy(), None, True, 0.1)
    assert res.n == "5 instances" and res.p == pytest.approx(expected.p, rel=1e-12)
    assert res.effect == pytest.approx(expected.effect)
    inter = claim(test="interaction", scenes=("studio", "drift"))
    res = claim_compare.compare(df, inter, inter.scenes)
    both = df[df.instance > 0].groupby(["instance_of", "instance", "variant"]).psnr.mean().unstack("variant")
    d = (both.cc - both.baseline)
    expected = C.compare_means(d.loc["studio"].to_numpy(), d.loc["drift"].to_numpy(), False, 0.1)
    assert res.p == pytest.approx(expected.p, rel=1e-12) and res.n == "5 vs 5 instances"
    assert "per-instance" in res.method


def test_one_instance_keeps_todays_test_bit_for_bit_and_unit_seed_keeps_the_seeds() -> None:
    one = frame(1, seeds=6)
    c = claim()
    with_cols = claim_compare.compare(one, c, c.scenes)
    without = claim_compare.compare(one.drop(columns=["instance_of", "instance"]), c, c.scenes)
    assert (with_cols.method, with_cols.n) == ("paired t (by scene and seed)", "6 pairs")
    assert (with_cols.effect, with_cols.p, with_cols.p_tost, with_cols.ci, with_cols.statistic) == (
        without.effect, without.p, without.p_tost, without.ci, without.statistic)
    assert V.evaluate(one, [c]).iloc[0].unit == "seeds of 1 instance"
    # a claim with the seed as its unit (run-to-run, a variance) reads the scene as written only: a
    # fresh instance's runs never enter it
    many, seed_unit = frame(4), claim(unit="seed")
    res = claim_compare.compare(many, seed_unit, seed_unit.scenes)
    pilot = claim_compare.compare(many[many.instance == 0], seed_unit, seed_unit.scenes)
    assert (res.method, res.n) == ("paired t (by scene and seed)", "3 pairs") and (res.p, res.ci) == (pilot.p, pilot.ci)
    assert V.evaluate(many, [seed_unit]).iloc[0].unit == "seeds of 1 instance"
    spread = claim(test="variance", expect="lower")
    assert claim_compare.compare(many, spread, spread.scenes).n == "3 pairs"


def test_a_claim_over_two_scenes_splits_by_the_scene_as_written_over_instance_means() -> None:
    df = frame(3, scenes=("studio", "drift"), seed=3)
    c = claim(scenes=("studio", "drift"))
    p_het, per_scene = claim_compare.scene_split(df, c)
    assert list(per_scene) == ["studio", "drift"]
    means = df.groupby(["variant", "instance_of", "instance"]).psnr.mean().unstack("variant")
    d = means.cc - means.baseline
    d = d[d.index.get_level_values("instance") > 0]  # the pilot instance 0 left out
    assert per_scene["studio"] == pytest.approx(d.loc["studio"].mean())
    assert np.isfinite(p_het)
    assert claim_compare.compare(df, c, c.scenes).n == "4 instances"
    assert IU.unit_text(df, c, c.scenes) == "4 instances of 2 scenes, pilot instance 0 left out"
    seed_unit = claim(scenes=("studio", "drift"), unit="seed")
    assert IU.unit_text(df, seed_unit, c.scenes) == "seeds of 1 instance of each of 2 scenes"
    assert IU.unit_text(frame(1, scenes=("studio", "drift")), c, c.scenes) == "seeds of 1 instance of each of 2 scenes"


# --------------------------------------------------------------------------- registration


def test_the_unit_and_instances_register_a_claim_only_when_they_change_its_test() -> None:
    raw = copy.deepcopy(MINI_STUDY)
    first = registration.claim_fingerprint(raw, {}, "cc_mean")
    raw["claims"][0]["unit"] = "instance"  # the default written out
    assert registration.claim_fingerprint(raw, {}, "cc_mean") == first
    raw["claims"][0]["unit"] = "seed"  # on one instance the seed is the unit either way
    assert registration.claim_fingerprint(raw, {}, "cc_mean") == first
    raw["profiles"]["quick"]["scenes"][0]["instances"] = 1
    assert registration.claim_fingerprint(raw, {}, "cc_mean") == first
    raw["profiles"]["quick"]["scenes"][0]["instances"] = 3
    # a claim with the seed as its unit reads the scene as written only: the draws change nothing of it
    assert registration.claim_fingerprint(raw, {}, "cc_mean") == first
    del raw["claims"][0]["unit"]  # now it takes the instance as its unit: another test, re-registered
    by_instance = registration.claim_fingerprint(raw, {}, "cc_mean")
    assert by_instance != first and json.loads(by_instance)["scenes"]["easy"]["instances"] == 3.0
    spread = dict(raw["claims"][0], id="spread", test="variance", expect="lower")  # never takes instances
    raw["claims"].append(spread)
    no_draws = copy.deepcopy(raw)
    no_draws["profiles"]["quick"]["scenes"][0]["instances"] = 1
    assert registration.claim_fingerprint(raw, {}, "spread") == registration.claim_fingerprint(no_draws, {}, "spread")
    raw["profiles"]["quick"]["scenes"][0]["instances"] = 12  # a fixed-n claim's n: another test
    assert registration.claim_fingerprint(raw, {}, "cc_mean") != by_instance
    # run until decided: its registered plan bounds what it reads, so more draws change nothing
    raw["profiles"]["quick"]["sequential"] = {"first": 3}
    planned = registration.claim_fingerprint(raw, {}, "cc_mean")
    raw["profiles"]["quick"]["scenes"][0]["instances"] = 30
    assert registration.claim_fingerprint(raw, {}, "cc_mean") == planned
    assert json.loads(planned)["scenes"]["easy"]["instances"] == "several"


# --------------------------------------------------------------------------- committed reports


def test_the_span_of_each_counted_method_claim_is_listed_from_its_runs() -> None:
    claims = (claim(id="wide"), claim(id="two", scenes=("studio", "drift")), claim(id="seedy", unit="seed"),
              claim(id="spread", test="variance", expect="lower"), claim(id="old", withdrawn="superseded"),
              claim(id="conv", group="convention"), claim(id="ext", group="extension", b=""))
    df = pd.concat([frame(3), frame(1, scenes=("drift",))], ignore_index=True)
    rows = pd.DataFrame(instance_span.claim_spans("study", claims, df, Register()))
    assert list(rows.claim) == ["wide", "two", "ext"]
    # the tested instances: studio's fresh 1 and 2 (its pilot instance 0 left out); drift's only one
    assert list(rows.instances) == [2, 1, 2]
    assert rows.set_index("claim").per_scene["two"] == "studio: 2, drift: 1"
    assert list(rows.most_instances) == [2, 2, 2]
    assert rows.set_index("claim").runs["wide"] == 12  # 2 arms x 2 fresh instances x 3 seeds
    # a run-to-run study's claims are not method claims about a kind of scene; no runs span nothing
    assert instance_span.claim_spans("secret5_cc", claims, df, Register()) == []
    bare = instance_span.claim_spans("study", claims[:1], None, Register())
    assert bare[0]["instances"] == 0 and bare[0]["runs"] == 0
    # an old runs.csv without the columns: every scene is one instance
    old = instance_span.claim_spans("study", claims[:1], frame(1).drop(columns=["instance_of", "instance"]),
                                    Register())
    assert old[0]["instances"] == 1 and old[0]["most_instances"] == 1


def test_the_committed_reports_list_every_counted_method_claim() -> None:
    spans = instance_span.committed_spans(ROOT / "reports", ROOT / "studies")
    assert len(spans) and list(spans.columns) == instance_span.COLUMNS
    assert not spans.study.isin(instance_span.RUN_TO_RUN_STUDIES).any()
    # issue 57's check: every counted method claim with runs spans 3 or more instances on each of its
    # scenes (the fewest of any of them), and one without runs is about scenes the quick profile does
    # not draw (the real datasets')
    ran = spans[spans.runs > 0]
    assert (ran.instances >= 3).all(), ran[ran.instances < 3][["study", "claim", "per_scene"]].to_string()
    assert (ran.most_instances >= ran.instances).all()
    for _, row in spans[spans.runs == 0].iterrows():
        drawn = {sc.name.partition("@")[0] for sc in load_study(row.study).profiles["quick"].scenes}
        assert not set(row.scenes.split(", ")) & drawn, row.claim


def test_registration_is_judged_on_the_runs_the_test_reads_not_the_pilots() -> None:
    """The pilot instance's runs came before instances existed; "registered before its runs" looks
    at the earliest run the claim's test reads (``registration._claim_runs``)."""
    df = frame(3)
    read = registration._claim_runs(claim(), df)
    assert sorted(set(read.instance)) == [1, 2] and len(read) == 12
    assert sorted(set(registration._claim_runs(claim(unit="seed"), df).instance)) == [0]  # the seed its unit
    assert len(registration._claim_runs(claim(), frame(1))) == 6  # no fresh instance: the pilot's runs are all


def test_an_instance_level_test_waits_for_every_drawn_instance_and_drops_the_pilot_from_the_start() -> None:
    """Its n is the count drawn (registered), not the count finished so far; and the pilot is left
    out as soon as the scene is drawn several times, not when a fresh run happens to finish."""
    df = frame(5)
    c = claim(test="contrast", contrasts=((("cc", 1.0), ("baseline", -1.0)),), a="", b="")
    late = df.copy()
    late.loc[late.instance == 4, ["status", "psnr"]] = ["MISSING", np.nan]  # instance 4 not run yet
    with pytest.raises(ValueError, match="18 of the 24 runs of its arms on fresh instances have run"):
        claim_compare.compare(late, c, c.scenes)
    assert V.evaluate(late, [c]).iloc[0].verdict == V.NOT_TESTED
    late.loc[late.instance == 4, "status"] = "FAILED"  # a failed run has run: the instance drops out
    assert claim_compare.compare(late, c, c.scenes).n == "3 instances"
    # nothing fresh has finished: still no test on the pilot's seeds
    early = df.assign(status=np.where(df.instance > 0, "MISSING", "FINISHED"))
    with pytest.raises(ValueError, match="0 of the 24"):
        claim_compare.compare(early, claim(), ("studio",))


def test_a_claim_mixing_drawn_and_undrawn_scenes_is_refused_with_one_line() -> None:
    raw = mini(3)
    raw["profiles"]["quick"]["scenes"].append({"name": "plain", "synth": {"preset": "studio", "seed": 9},
                                              "variants": ["baseline", "cc"]})
    raw["claims"][0]["scenes"] = ["easy", "plain"]
    with pytest.raises(InputError, match=r"claims\.cc_mean\.scenes: profile quick draws .* but not plain") as err:
        parse_study(copy.deepcopy(raw), Path("mini.yaml"))
    assert "\n" not in str(err.value)
    raw["claims"][0]["unit"] = "seed"  # reads the scenes as written: consistent
    assert parse_study(raw, Path("mini.yaml")).claims[0].unit == "seed"


def test_the_study_page_shows_a_scenes_fresh_instances_as_one_column_beside_the_pilot() -> None:
    from harness.report import sections
    from harness.report.results import FRESH, ReportData

    study = parse_study(mini(4), Path("mini.yaml"))
    df = frame(4).assign(scene=lambda d: d.scene.str.replace("studio", "easy"),
                         instance_of="easy")[["variant", "scene", "instance_of", "instance", "seed", "status", "psnr"]]
    df = df.assign(failure="", error="", diverged=False, wall_seconds=1.0, run_id="r")
    data = ReportData(study, Selection(), [], df, "", "", [], None)
    assert list(dict.fromkeys(data.shown().scene)) == ["easy", f"easy{FRESH}"]
    assert data.labels()[f"easy{FRESH}"] == "easy, 3 fresh instances"
    tabs, summaries = sections.build_tables(data)
    assert tabs[0].columns[:2] == ["easy", "easy, 3 fresh instances"]
    # the fresh column's mean is the mean over the fresh instances' runs, its n their count of runs
    cc = summaries["psnr"].set_index(["variant", "scene"]).loc[("cc", f"easy{FRESH}")]
    want = df[(df.variant == "cc") & (df.instance > 0)].psnr
    assert cc["mean"] == pytest.approx(want.mean()) and int(cc["n"]) == len(want)
    plain = ReportData(study, Selection(), [], df[df.instance == 0], "", "", [], None)
    assert plain.shown() is plain.df  # no fresh instances: the page as before
    page = sections.tables_section(data)
    assert "easy, 3 fresh instances" in str(page) and "one run each" in str(page)


def test_a_committed_report_written_before_instances_is_read_with_the_fresh_runs_now_planned() -> None:
    """A runs.csv made before its scenes had instances lists no fresh run; the committed-report
    path adds them as MISSING, so its instance-level claims wait instead of testing the pilot."""
    from harness.report.families import with_fresh_planned

    study = parse_study(mini(3), Path("mini.yaml"))
    old = frame(1, seeds=2).assign(scene="easy", instance_of="easy").drop(columns=["instance_of", "instance"])
    full = instance_columns(with_fresh_planned(old, study), study)
    added = full[full.instance > 0]
    assert sorted(set(added.scene)) == ["easy@1", "easy@2"] and set(added.status) == {"MISSING"}
    assert len(added) == 4  # 2 variants x 2 fresh instances x their one seed
    c = claim(scenes=("easy",))
    with pytest.raises(ValueError, match="0 of the 4 runs"):
        claim_compare.compare(full, c, c.scenes)
    assert with_fresh_planned(full, study).equals(full)  # nothing more to add


def test_a_pages_run_count_names_scenes_and_their_fresh_instances_not_every_draw_a_scene() -> None:
    from harness.report.writer import _grid

    rows = [("base", "studio", s, "studio", 0) for s in range(3)] + \
        [(v, f"{b}@{i}", 0, b, i) for v in ("base", "cc") for b in ("studio", "drift") for i in (1, 2)]
    df = pd.DataFrame(rows, columns=["variant", "scene", "seed", "instance_of", "instance"])
    assert _grid(len(df), df) == ("over 2 variants, 2 scenes (2 fresh instances of each, one seed an instance) and"
                                  " 3 seeds (not every variant on every scene and seed)")
