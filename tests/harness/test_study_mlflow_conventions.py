"""Runs carry MLflow's own conventions: experiment kind, source tags, the scene as a dataset
input, and system metrics from MLflow's sampler; the profile in every run's name and tags, so
runs of one study under two profiles are told apart (and grouped apart by the study view)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest
from conftest import TOY_STUDIES
from fakes import fake_generate, fake_train

from harness.run.runner import run_study
from harness.spec.runs import Selection
from harness.tracking.conventions import VIEW_TAG_PREFIX, folder_fingerprint, run_name, scene_dataset
from harness.tracking.provenance import git_sha
from harness.tracking.records import load_runs, open_store


def test_study_runs_follow_mlflow_conventions(workdir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MLFLOW_SYSTEM_METRICS_SAMPLING_INTERVAL", "0.1")
    monkeypatch.setenv("FAKE_TRAIN_SLEEP", "0.6")
    out = run_study("toy", Selection(variants=["cc"], seeds=1), studies_dir=TOY_STUDIES, train_fn=fake_train,
                    generate=fake_generate, echo=lambda s: None)
    assert out.finished == 1
    store = open_store(f"sqlite:///{Path('mlflow.db').resolve()}")
    exp = store.client.get_experiment_by_name("ftgspp/toy")
    assert exp.tags["mlflow.experimentKind"] == "custom_model_development", "UI opens on the training runs"
    (rec,) = load_runs(store, "ftgspp/toy", "toy")
    (parent,) = load_runs(store, "ftgspp/toy", "toy", kind="study")
    sha = git_sha()
    for r in (rec, parent):
        assert r.tags["mlflow.source.name"] == "study run toy --profile quick --seeds 1 --variants cc"
        assert r.tags["mlflow.source.type"] == "LOCAL"
        if sha != "unknown":
            assert r.tags["mlflow.source.git.commit"] == sha.removesuffix("-dirty")
    run = store.client.get_run(rec.run_id)
    (inp,) = run.inputs.dataset_inputs
    ds = inp.dataset
    synth = {"layout": "dynerf", "preset": "studio", "seed": 0}
    assert ds.name == "easy" and ds.source_type == "synthetic"
    assert json.loads(ds.source) == {"generator": "ftgspp.data.synthetic.build.generate", "args": synth}
    assert ds.digest == hashlib.sha256(json.dumps(synth, sort_keys=True).encode()).hexdigest()[:16]
    assert json.loads(ds.profile)["format"] == "dynerf"
    assert {t.key: t.value for t in inp.tags} == {"mlflow.data.context": "train"}
    (parent_input,) = store.client.get_run(parent.run_id).inputs.dataset_inputs
    assert parent_input.dataset.digest == ds.digest, "the parent row shows the study's scenes"
    system = {k for k in rec.metrics if k.startswith("system/")}
    assert {"system/cpu_utilization_percentage", "system/system_memory_usage_megabytes"} <= system


def test_runs_of_two_profiles_carry_their_profile_in_name_and_tags(workdir: Path) -> None:
    """A quick and a smoke run of one study: the same (variant, scene, seed) twice, never under
    one name; the study view's groups split by profile, so no group row averages the two."""
    quiet = dict(studies_dir=TOY_STUDIES, train_fn=fake_train, generate=fake_generate, echo=lambda s: None)
    for profile in ("quick", "smoke"):
        assert run_study("toy", Selection(profile=profile, variants=["baseline", "cc"], seeds=1), **quiet).finished == 2
    store = open_store(f"sqlite:///{Path('mlflow.db').resolve()}")
    runs = load_runs(store, "ftgspp/toy", "toy")
    assert sorted(r.tags["profile"] for r in runs) == ["quick", "quick", "smoke", "smoke"]
    for r in runs:
        label = f"{r.tags['variant']}/{r.tags['scene']}/seed{r.tags['seed']}"
        assert r.tags["mlflow.runName"] == run_name(label, r.tags["profile"]) == f"{label} [{r.tags['profile']}]"
    assert len({r.tags["mlflow.runName"] for r in runs}) == 4, "no two runs share a name"
    parents = load_runs(store, "ftgspp/toy", "toy", kind="study")
    assert [p.tags["profile"] for p in parents] == ["quick", "smoke"]
    assert [p.tags["mlflow.runName"].split("-")[1] for p in parents] == ["quick", "smoke"]

    # the study view's groups, as the UI forms them: one per value of its group-by tags
    exp = store.client.get_experiment_by_name("ftgspp/toy")
    view = json.loads(exp.tags[VIEW_TAG_PREFIX + "ftgspp-study"])
    keys = [k["groupByData"] for k in view["groupBy"]["groupByKeys"]]
    shown = store.client.search_runs([exp.experiment_id], filter_string=view["searchFilter"])
    groups: dict[tuple[str, ...], set[str]] = {}
    for run in shown:
        groups.setdefault(tuple(run.data.tags[k] for k in keys), set()).add(run.data.tags["profile"])
    assert len(groups) == 4 and all(len(profiles) == 1 for profiles in groups.values()), groups


def test_real_scene_dataset_is_fingerprinted_by_its_files(tmp_path: Path) -> None:
    (tmp_path / "cam00.mp4").write_bytes(b"x" * 10)
    (tmp_path / "poses_bounds.npy").write_bytes(b"y" * 3)
    inp = scene_dataset("coffee", str(tmp_path), "dynerf", None)
    want = hashlib.sha256(b"cam00.mp4\x0010\nposes_bounds.npy\x003\n").hexdigest()[:16]
    assert inp.dataset.digest == want == folder_fingerprint(tmp_path)
    assert inp.dataset.source_type == "local" and json.loads(inp.dataset.source)["uri"] == str(tmp_path.resolve())
    (tmp_path / "cam01.mp4").write_bytes(b"z")
    assert folder_fingerprint(tmp_path) != want


def test_runs_of_one_scene_starting_together_all_get_the_dataset(workdir: Path) -> None:
    """MLflow inserts a dataset row check-then-insert; simultaneous runs of one scene race
    (behind a server there is no client-side lock to serialise them). All must get it."""
    import threading

    from harness.tracking.store import Store

    uri = f"sqlite:///{Path('mlflow.db').resolve()}"
    main = Store(uri)
    exp = main.experiment_id("race")
    run_ids = [main.create_run(exp, f"r{i}", {}) for i in range(6)]
    dataset = scene_dataset("easy", "data/synth/easy", "dynerf", {"layout": "dynerf", "preset": "studio", "seed": 0})
    gate = threading.Barrier(len(run_ids))
    errors: list[BaseException] = []

    def log(run_id: str) -> None:
        store = Store(uri)
        store._lock_path = None  # as over HTTP: the server does not serialise these writes
        gate.wait()
        try:
            store.log_inputs(run_id, [dataset])
        except BaseException as exc:  # collected: the assertion below names it
            errors.append(exc)

    threads = [threading.Thread(target=log, args=(r,)) for r in run_ids]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors[0]
    for run_id in run_ids:
        (inp,) = main.client.get_run(run_id).inputs.dataset_inputs
        assert inp.dataset.digest == dataset.dataset.digest


def test_trainer_fingerprint_follows_the_training_code_only(tmp_path: Path) -> None:
    """A change to the trainer's code or configs changes the fingerprint; a change to the
    benchmarks (never imported by training) or to the harness does not."""
    from harness.tracking.provenance import trainer_fingerprint

    for rel in ("ftgspp/render/cpu.py", "ftgspp/bench/render.py", "conf/train.yaml", "harness/x.py"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text("a = 1\n")
    base = trainer_fingerprint.__wrapped__(tmp_path)
    for rel, changes in (("ftgspp/bench/render.py", False), ("harness/x.py", False),
                         ("ftgspp/render/cpu.py", True), ("conf/train.yaml", True)):
        (tmp_path / rel).write_text("a = 2\n")
        assert (trainer_fingerprint.__wrapped__(tmp_path) != base) is changes, rel
        (tmp_path / rel).write_text("a = 1\n")
