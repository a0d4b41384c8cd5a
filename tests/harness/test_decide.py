"""``study decide`` (issue 57: runs until decided), on synthetic runs frames — no training but the
last test's fake trainer: the replay of a family's rounds from its runs is ``decide_family``
called round by round on the runs in seed order (and a ``runs.csv`` gives the same answer); a
family never reads another's runs; a claim with the runs of look 1 only continues and asks for
look 2's count, runs beyond a look wait for it and a run missing in the middle holds back the
ones after it; at its cap a claim says what a fixed design would need; bad input is one line and
exit status 2; a claim's plan registers it; ``--until-decided`` runs round after round."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from ftgspp.errors import InputError
from harness.spec.instances import compact_ranges, expand_ranges
from harness.analysis import sequential as Q, sequential_study as S, stats
from harness.cli import decide as D, study
from harness.spec import registration, study_files
from harness.spec.paper_register import Register

SEQ_STUDY = {
    "name": "seq",
    "question": "Which changes raise PSNR, decided round by round?",
    "baseline": "base",
    "variants": {"base": [], "cc": ["model.color_correction=true"], "gate": ["model.gate=true"], "free": []},
    "claims": [
        {"id": "cc_mean", "claim": "CC raises PSNR.", "metric": "psnr", "test": "mean", "a": "cc", "b": "base",
         "scenes": ["studio"], "expect": "higher"},
        {"id": "gate_mean", "claim": "The gate raises PSNR.", "metric": "psnr", "test": "mean", "a": "gate",
         "b": "base", "scenes": ["studio", "drift"], "expect": "higher", "plan": {"first": 4}},
        {"id": "free_welch", "claim": "Free init lowers PSNR.", "metric": "psnr", "test": "mean", "a": "free",
         "b": "base", "scenes": ["studio"], "expect": "lower", "pair": "none", "group": "extension"},
        {"id": "cc_spread", "claim": "CC lowers the spread.", "metric": "psnr", "test": "variance", "a": "cc",
         "b": "base", "scenes": ["studio"], "expect": "lower"},
        {"id": "old", "claim": "Withdrawn.", "metric": "psnr", "test": "mean", "a": "cc", "b": "base",
         "scenes": ["studio"], "expect": "higher", "withdrawn": "superseded"},
    ],
    "profiles": {"quick": {
        "seeds": 3, "overrides": ["profile=smoke"], "run_seconds": 36, "command": "study run seq",
        "scenes": [{"name": "studio", "synth": {"preset": "studio"}}, {"name": "drift", "synth": {"preset": "studio"}}],
        "sequential": {"first": 3, "per_round": 2, "rounds": 4, "study_cap_cpu_hours": 2.0}}},
}
EFFECTS = {"base": 0.0, "cc": 0.05, "gate": 0.2, "free": -1.5}  # psnr shifts; noise SD 1 (SESOI 0.2 dB)


def _study(raw: dict = SEQ_STUDY, name: str = "seq"):
    return study_files.parse_study(copy.deepcopy(raw), Path(f"{name}.yaml"))


def _design() -> S.Design:
    return S.design(_study(), "quick", Register())


def _frame(seeds: dict[str, int], rng_seed: int = 0, failed: tuple = ()) -> pd.DataFrame:
    """Runs of every variant on both scenes, seeds 0..seeds[variant]-1 finished (the rest of 12
    MISSING); ``failed``: (variant, scene, seed) recorded FAILED. A variant's noise per cell is
    the same whatever the other variants' seed counts."""
    rows = []
    for i, (v, effect) in enumerate(EFFECTS.items()):
        rng = np.random.default_rng([rng_seed, i])
        noise = rng.normal(0, 1, (2, 12))
        for j, scene in enumerate(("studio", "drift")):
            for seed in range(12):
                status = "FINISHED" if seed < seeds.get(v, 0) and (v, scene, seed) not in failed else \
                    "FAILED" if (v, scene, seed) in failed else "MISSING"
                psnr = 30 + effect + noise[j, seed] if status == "FINISHED" else np.nan
                rows.append({"variant": v, "scene": scene, "seed": seed, "status": status, "psnr": psnr})
    return pd.DataFrame(rows)


def _by_hand(df: pd.DataFrame, a: str, b: str, scenes: tuple[str, ...]) -> np.ndarray:
    """a − b per (seed, scene), seed by seed, each seed's scenes in the claim's order."""
    ok = df[df.status == "FINISHED"].set_index(["variant", "scene", "seed"]).psnr
    out = []
    for seed in range(12):
        for s in scenes:
            if (a, s, seed) not in ok or (b, s, seed) not in ok:
                return np.array(out)
            out.append(ok[(a, s, seed)] - ok[(b, s, seed)])
    return np.array(out)


def test_the_plan_is_the_claims_over_the_profiles_and_families_are_the_counted_groups() -> None:
    d = _design()
    assert {f: [c.spec.id for c in cs] for f, cs in d.families.items()} == {
        "paper": ["cc_mean", "gate_mean"], "extension": ["free_welch"]}
    cc, gate = d.families["paper"]
    assert cc.plan.schedule() == (3, 5, 7, 9) and gate.plan.schedule() == (4, 6, 8, 10)
    assert cc.plan.cpu_hours_per_run == pytest.approx(0.01) and cc.plan.arms == 2
    assert gate.cells(5) == [("studio", 0), ("drift", 0), ("studio", 1), ("drift", 1), ("studio", 2)]
    assert dict(d.left_out) == {"cc_spread": "a variance claim: the report decides it at fixed n",
                                "old": "not counted (withdrawn, evidence or replaced)"}
    # worst case: the union of every claim's runs at its cap (base on studio shared by all three)
    gate_runs = {(v, sc, s) for v in ("gate", "base") for sc in ("studio", "drift") for s in range(5)}
    assert d.worst_case() == len({(v, "studio", s) for v in ("cc", "base", "free") for s in range(9)} | gate_runs)
    assert _study().profile("smoke").sequential == _study().profile("quick").sequential


def test_the_replay_is_decide_family_round_by_round_on_the_runs_in_seed_order(tmp_path: Path) -> None:
    d = _design()
    df = _frame({"base": 9, "cc": 5, "gate": 5, "free": 9})  # cc lacks look 3 (7 pairs)
    (paper, _) = S.decide(d, df)
    cc, gate = d.families["paper"]
    arrays = {"cc_mean": _by_hand(df, "cc", "base", ("studio",)), "gate_mean": _by_hand(df, "gate", "base",
                                                                                         ("studio", "drift"))}
    state, rounds = None, 0
    for k in range(4):
        looks = {c.spec.id: c.plan.schedule()[k] for c in (cc, gate)}
        if any(not (state or {}).get(i, {}).get("rejected") and len(arrays[i]) < n for i, n in looks.items()):
            break
        now = [Q.Claim(c.spec.id, arrays[c.spec.id][:looks[c.spec.id]], None, 0.2, plan=c.plan) for c in (cc, gate)]
        decisions, state = Q.decide_family(now, state, alpha=stats.ALPHA * 2 / 3)  # 2 of the group's 3 claims
        rounds += 1
    assert rounds == paper.rounds == 2 and paper.state == state
    assert [o.decision for o in paper.outcomes] == decisions
    assert paper.outcomes[0].status == Q.CONTINUE and paper.outcomes[0].needs == 7  # it asks for look 3's pairs
    # an outside recomputation from a runs.csv gives the same answer
    df.to_csv(tmp_path / "runs.csv", index=False)
    again = S.decide(d, pd.read_csv(tmp_path / "runs.csv"))
    assert [[o.decision for o in f.outcomes] for f in again] == [[o.decision for o in f.outcomes]
                                                                 for f in S.decide(d, df)]


def test_the_sequential_claims_hold_their_share_of_the_groups_alpha_over_every_study() -> None:
    """A group is one family over every study (the report's fixed-n Holm): the sequential claims
    of one study take α × theirs / all the group's counted claims, fixed from the study files."""
    d = _design()
    # paper: cc_mean, gate_mean and the variance claim cc_spread count (old is withdrawn)
    assert d.shares == {"paper": (3, pytest.approx(stats.ALPHA * 2 / 3)), "extension": (1, stats.ALPHA)}
    other = copy.deepcopy(SEQ_STUDY) | {"name": "other"}
    other["claims"] = [dict(c, id=f"o_{c['id']}") for c in other["claims"]]  # 3 more paper claims, 1 extension
    with_other = S.design(_study(), "quick", Register(), lambda: {"other": _study(other, "other")})
    assert with_other.shares == {"paper": (6, pytest.approx(stats.ALPHA / 3)), "extension": (2, stats.ALPHA / 2)}
    df = _frame({"base": 9, "cc": 9, "gate": 9, "free": 9})
    shared = [o.decision.share for f in S.decide(with_other, df) for o in f.outcomes]
    alone = [o.decision.share for f in S.decide(d, df) for o in f.outcomes]
    assert all(a < b for a, b in zip(shared, alone))  # the same runs, each hypothesis at a smaller level
    lines = D.plan_lines(with_other, "obf")
    assert any("family paper: 2 claims here of 6 that count in it over every study: α 0.0167 of its 0.05" in x
               for x in lines)


def test_a_family_never_reads_another_familys_runs() -> None:
    d = _design()
    first = S.decide(d, _frame({"base": 9, "cc": 9, "gate": 9, "free": 9}))
    other = _frame({"base": 9, "cc": 9, "gate": 9, "free": 9}, rng_seed=1)  # new free (extension) runs only
    same = _frame({"base": 9, "cc": 9, "gate": 9, "free": 9})
    same.loc[same.variant == "free", "psnr"] = other.loc[other.variant == "free", "psnr"].to_numpy() + 3.0
    second = S.decide(d, same)
    assert [o.decision for o in second[0].outcomes] == [o.decision for o in first[0].outcomes]
    assert second[0].state == first[0].state
    assert second[1].outcomes[0].decision != first[1].outcomes[0].decision


def test_look_one_only_continues_runs_beyond_a_look_wait_and_a_gap_holds_back_the_rest() -> None:
    d = _design()
    none = S.decide(d, _frame({"base": 3, "cc": 3, "gate": 1, "free": 3}))[0]  # gate's first look: 4 pairs
    assert none.rounds == 0 and all(o.decision is None and o.status == Q.CONTINUE for o in none.outcomes)
    assert [o.needs for o in none.outcomes] == [3, 4]
    three = S.decide(d, _frame({"base": 3, "cc": 3, "gate": 2, "free": 3}))
    paper, extension = three
    assert paper.rounds == extension.rounds == 1  # look 1 read: each continuing claim asks for look 2's count
    assert [o.needs for f in three for o in f.outcomes] == [5, 6, 5]
    assert all(o.status == Q.CONTINUE and o.decision.look == 1 for f in three for o in f.outcomes)
    four = S.decide(d, _frame({"base": 4, "cc": 4, "gate": 2, "free": 4}))  # a 4th seed waits for look 2
    assert [o.decision for f in four for o in f.outcomes] == [o.decision for f in three for o in f.outcomes]
    assert four[1].outcomes[0].runs.n == 4
    nxt = S.next_round(d, three, _frame({"base": 3, "cc": 3, "gate": 2, "free": 3}))
    assert (nxt.variants, nxt.scenes, nxt.seeds) == (("cc", "base", "gate", "free"), ("studio", "drift"), 5)
    # the next looks read cc, base and free seeds 3-4 on studio and gate's seed 2 on both scenes; the one
    # command runs all 4 variants x 2 scenes x 5 seeds, 22 of them finished
    assert (nxt.own, nxt.runs) == (8, 40 - 22)
    # base's seed 1 on studio failed: every later cell of its claims waits for it to be run again
    gap = _frame({"base": 9, "cc": 9, "gate": 9, "free": 9}, failed=(("base", "studio", 1),))
    held = S.decide(d, gap)
    assert [o.runs.n for f in held for o in f.outcomes] == [1, 2, 1] and all(f.rounds == 0 for f in held)
    nxt = S.next_round(d, held, gap)
    assert nxt.own == 1 and nxt.runs == 1  # the failed run, run again; nothing after it is missing


def test_at_its_cap_a_claim_says_how_many_runs_a_fixed_design_needs() -> None:
    d = _design()
    df = _frame({"base": 9, "cc": 9, "gate": 5, "free": 9})
    paper, _ = S.decide(d, df)
    cc = paper.outcomes[0]
    assert cc.status == Q.AT_CAP and cc.decision.n == 9 and not cc.decision.rejected
    rejected = sum(len(o.decision.rejected) for o in paper.outcomes)
    share = d.alpha("paper") / (4 - rejected)  # its share of the group's α (2 of 3 claims), Holm within
    sd = float(np.std(_by_hand(df, "cc", "base", ("studio",))[:9], ddof=1))
    assert cc.decision.share == pytest.approx(share)
    assert cc.decision.runs_needed == stats.n_for_t(0.2, sd, True, share)
    line = D._at_cap(d, cc)
    seeds = int(cc.decision.runs_needed)
    assert f"needs {seeds} pairs" in line
    assert f"study run seq --profile quick --launcher slurm --seeds {seeds} --scenes studio --variants cc,base" in line


def _instances_study(k: int) -> dict:
    """SEQ_STUDY with studio drawn ``k`` times and only cc_mean (on studio) counted."""
    raw = copy.deepcopy(SEQ_STUDY)
    raw["claims"] = [raw["claims"][0]]
    raw["profiles"]["quick"]["scenes"][0]["instances"] = k
    return raw


def _instance_frame(fresh: int, rng_seed: int = 4) -> pd.DataFrame:
    """cc and base at seed 0 on instances 1..fresh of studio; the pilot (instance 0) with 3 seeds
    and an effect of +9 dB that no instance-level look may read."""
    rng = np.random.default_rng(rng_seed)
    rows = []
    for i in range(fresh + 1):
        level, effect = rng.normal(30, 1), rng.normal(0.1, 0.5)
        for seed in range(3 if i == 0 else 1):
            for v, shift in (("base", 0.0), ("cc", 9.0 if i == 0 else effect)):
                rows.append({"variant": v, "scene": "studio" if i == 0 else f"studio@{i}", "instance_of": "studio",
                             "instance": i, "seed": seed, "status": "FINISHED",
                             "psnr": level + shift + rng.normal(0, 0.05)})
    return pd.DataFrame(rows)


def test_with_instances_a_claim_adds_fresh_instances_and_never_reads_the_pilot() -> None:
    with pytest.raises(InputError, match="draws 5 fresh instances"):  # cap 9 paired instances, 5 drawn
        S.design(_study(_instances_study(6)), "quick", Register())
    d = S.design(_study(_instances_study(10)), "quick", Register())
    (cc,) = d.families["paper"]
    assert cc.fresh == 9 and cc.unit == "paired instances" and cc.seeds(9) == 1
    assert cc.cells(3) == [("studio@1", 0), ("studio@2", 0), ("studio@3", 0)]
    assert S.selection(d).scenes == [f"studio@{i}" for i in range(1, 10)] and S.selection(d).seeds == 1
    df = _instance_frame(5)
    (paper,) = S.decide(d, df)
    # by hand: cc − base per fresh instance in instance order, looks 3 and 5, at the study's share
    ok = df[df.instance > 0].set_index(["variant", "instance"]).psnr
    diffs = np.array([ok[("cc", i)] - ok[("base", i)] for i in range(1, 6)])
    state = None
    for n in (3, 5):
        decisions, state = Q.decide_family([Q.Claim("cc_mean", diffs[:n], None, 0.2, plan=cc.plan)], state,
                                           alpha=d.alpha("paper"))
    assert [o.decision for o in paper.outcomes] == decisions and paper.outcomes[0].runs.n == 5
    assert paper.outcomes[0].needs == 7  # undecided at 5: the next round asks for instances 6 and 7 at seed 0
    nxt = S.next_round(d, [paper], df)
    assert (nxt.scenes, nxt.seeds, nxt.own) == (("studio@6", "studio@7"), 1, 4)
    assert "studio@6, studio@7, --seeds 1" in D._continuing(d, paper.outcomes[0], S.finished_runs(df))
    # the pilot's +9 dB changes nothing
    calm = df.assign(psnr=df.psnr.where(df.instance > 0, 30.0))
    assert [o.decision for o in S.decide(d, calm)[0].outcomes] == decisions


def _write(folder: Path, name: str, raw: dict) -> None:
    folder.mkdir(exist_ok=True)
    (folder / f"{name}.yaml").write_text(yaml.safe_dump({**copy.deepcopy(raw), "name": name}, sort_keys=False))


@pytest.mark.parametrize("case, words", [
    ("nosuch", "unknown study"),
    ("nomeans", "no mean claims"),
    ("noplan", "no sequential plan"),
    ("badplan", "must be at least 2"),
    ("variance_plan", "only a mean claim runs until decided"),
])
def test_bad_input_is_one_line_and_exit_status_2(case: str, words: str, tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    folder = tmp_path / "studies"
    profile = SEQ_STUDY["profiles"]["quick"]
    _write(folder, "nomeans", {**SEQ_STUDY, "claims": SEQ_STUDY["claims"][3:4]})
    _write(folder, "noplan", {**SEQ_STUDY, "profiles": {"quick": {k: v for k, v in profile.items()
                                                                    if k != "sequential"}}})
    _write(folder, "badplan", {**SEQ_STUDY, "profiles": {"quick": {**profile, "sequential": {"first": 1}}}})
    _write(folder, "variance_plan", {**SEQ_STUDY, "claims": [{**SEQ_STUDY["claims"][3], "plan": {"first": 3}}]})
    monkeypatch.setattr(study_files, "STUDIES_DIR", folder)
    with pytest.raises(SystemExit) as stop:
        study.main(["decide", case])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err, err


def test_the_printed_plan_decisions_and_next_round_command(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                           capsys) -> None:
    _write(tmp_path / "studies", "seq", SEQ_STUDY)
    monkeypatch.setattr(study_files, "STUDIES_DIR", tmp_path / "studies")
    df = _frame({"base": 3, "cc": 3, "gate": 1, "free": 3})
    monkeypatch.setattr(D, "read_runs", lambda d, echo: (type("Data", (), {"df": df})(), ""))
    assert study.main(["decide", "seq"]) == 0
    out = capsys.readouterr().out
    assert "paper / cc_mean (cc − base in psnr on studio, pairs): looks 3, 5, 7, 9; cap 9 pairs = 18 runs," \
        " 0.18 CPU h" in out
    assert "study: at most 4 rounds; worst case" in out and "cap 2 CPU h" in out
    assert "cc_mean: continue: look 1 needs 3 pairs, which it has" in out
    assert "free_welch: continue: look 2 needs 5 runs per arm; add 4 runs (free, base on studio, --seeds 5)" in out
    assert "gate_mean: continue: look 1 needs 4 pairs; add 2 runs (gate, base on studio, drift, --seeds 2)" in out
    command = "study run seq --profile quick --seeds 5 --scenes studio,drift --variants gate,base,free"
    assert f"next round: {command}\n" in out


def test_a_plan_registers_the_claim_and_no_plan_leaves_its_fingerprint_as_it_was() -> None:
    raw = copy.deepcopy(SEQ_STUDY)
    del raw["profiles"]["quick"]["sequential"]
    fingerprint = registration.claim_fingerprint(raw, {}, "cc_mean")
    assert '"plan"' not in fingerprint and '"sequential"' not in fingerprint
    raw["claims"][0]["plan"] = {"first": None}  # a key written out at its default changes nothing
    assert registration.claim_fingerprint(raw, {}, "cc_mean") == fingerprint
    raw["claims"][0]["plan"] = {"first": 4}
    assert registration.claim_fingerprint(raw, {}, "cc_mean") != fingerprint
    spread = registration.claim_fingerprint(raw, {}, "cc_spread")
    raw["profiles"]["quick"]["sequential"] = {"rounds": 6}  # a mean claim's plan comes from its profile too
    assert registration.claim_fingerprint(raw, {}, "cc_spread") == spread
    assert json.loads(registration.claim_fingerprint(raw, {}, "free_welch"))["sequential"] == {
        "quick": {"rounds": 6.0}}


@pytest.mark.slow
def test_until_decided_runs_round_after_round_and_tags_each_round(workdir: Path, fakes_on: None,
                                                                  monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    # the fake trainer: cc is base + 0.5 dB, both rising 0.25 dB a seed; Welch at 3 and 5 runs an arm
    # finds neither a difference nor equivalence, so the claim stops at its cap after two rounds
    raw = {"name": "seqfake", "question": "Does CC raise the fake trainer's PSNR?", "baseline": "baseline",
           "variants": {"baseline": [], "cc": ["model.color_correction=true"]},
           "claims": [{"id": "cc", "claim": "CC raises PSNR.", "metric": "psnr", "test": "mean", "a": "cc",
                       "b": "baseline", "scenes": ["easy"], "expect": "higher", "pair": "none"}],
           "profiles": {"quick": {"seeds": 2, "overrides": ["profile=smoke"], "run_seconds": 36,
                                  "scenes": [{"name": "easy", "synth": {"preset": "studio", "seed": 0}}],
                                  "sequential": {"first": 3, "per_round": 2, "rounds": 2,
                                                 "study_cap_cpu_hours": 1.0}}}}
    _write(workdir / "studies", "seqfake", raw)
    monkeypatch.setattr(study_files, "STUDIES_DIR", workdir / "studies")
    assert study.main(["decide", "seqfake", "--until-decided"]) == 0
    out = capsys.readouterr().out
    assert "until decided: at most 2 rounds, stopping before a round that would take the study beyond 1 CPU h" in out
    assert "cc: stop at cap (5 runs per arm at look 2" in out and out.count("next round: study run seqfake") == 2
    from harness.tracking.records import load_runs, open_store

    store = open_store(f"sqlite:///{(workdir / 'mlflow.db').resolve()}")
    runs = load_runs(store, "ftgspp/seqfake", "seqfake")
    assert len(runs) == 10 and all(r.status == "FINISHED" for r in runs)
    parents = load_runs(store, "ftgspp/seqfake", "seqfake", kind="study")
    assert [p.tags["sequential.round"] for p in parents] == ["1", "2"]
    assert [json.loads(p.tags["sequential.looks"]) for p in parents] == [{"cc": 3}, {"cc": 5}]


def test_at_its_cap_a_claim_on_instances_names_a_fixed_design_on_new_instances() -> None:
    """The fixed design a claim undecided at its cap would need reads instances its looks never read."""
    d = S.design(_study(_instances_study(10)), "quick", Register())
    (paper,) = S.decide(d, _instance_frame(9))
    (o,) = paper.outcomes
    assert o.status == Q.AT_CAP and o.runs.n == 9
    n = int(o.decision.runs_needed)
    line = D._at_cap(d, o)
    assert f"needs {n} paired instances" in line and f"on new instances 10–{9 + n} (`instances: {10 + n}` on studio" in line
    command = line.split(": study run ", 1)[1]
    named = command.split("--scenes ")[1].split(" ")[0]
    assert named == f"studio@10..{9 + n}" and "--seeds 1" in command  # a range (spec.instances.compact_ranges)
    assert expand_ranges([named]) == [f"studio@{i}" for i in range(10, 10 + n)]


def test_scene_ranges_write_out_and_back() -> None:
    names = ["studio", "transient@11", "long_slow@11", "transient@12", "long_slow@12", "transient@13",
             "studio@5", "studio@6", "studio@9"]
    short = compact_ranges(names)
    assert short == ["studio", "transient@11..13", "long_slow@11", "long_slow@12", "studio@5", "studio@6", "studio@9"]
    assert sorted(expand_ranges(short)) == sorted(names)
    with pytest.raises(InputError, match="run backwards"):
        expand_ranges(["studio@9..3"])
    from harness.cli.study import build_parser

    args = build_parser().parse_args(["run", "ablation", "--scenes", "studio,studio@2..4", "--scenes", "transient@7"])
    assert args.scenes == ["studio", "studio@2", "studio@3", "studio@4", "transient@7"]
