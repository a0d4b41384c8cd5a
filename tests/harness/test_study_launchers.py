"""Launchers and shared stores: submitit config composition, picklable jobs, the submitit
local executor end to end, and two concurrent ``study run`` invocations on one SQLite store."""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import pytest
from conftest import HERE, TOY_STUDIES, prepare_workdir
from fakes import LOSS_STEPS, fake_generate, fake_train

from harness.run.launchers import _at_most, launcher_overrides, local_slots
from harness.run.runner import run_study
from harness.run.task import JobInfo, RunTask
from harness.spec.runs import Selection
from harness.spec.schema import CONF_DIR, register
from harness.tracking.records import load_runs, open_store

EXP = "ftgspp/toy"


def _uri() -> str:
    return f"sqlite:///{Path('mlflow.db').resolve()}"


def _finished() -> dict:
    return {r.key: r for r in load_runs(open_store(_uri()), EXP, "toy") if r.status == "FINISHED"}


@pytest.mark.parametrize("launcher, target", [
    ("slurm", "hydra_plugins.hydra_submitit_launcher.submitit_launcher.SlurmLauncher"),
    ("local", "hydra_plugins.hydra_submitit_launcher.submitit_launcher.LocalLauncher"),
])
def test_submitit_launcher_configs_compose_with_a_shared_folder(launcher: str, target: str, tmp_path: Path) -> None:
    from hydra import compose, initialize_config_dir

    sweep = tmp_path / "nfs" / "sweep"
    register()
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose("train", [*launcher_overrides(launcher, sweep, 1, "study_toy"), "hydra.launcher.timeout_min=30"],
                      return_hydra_config=True)
    hl = cfg.hydra.launcher
    assert hl._target_ == target
    assert hl.submitit_folder == f"{sweep.as_posix()}/.submitit/%j", "next to the sweep, never /tmp"
    assert hl.timeout_min == 30 and hl.name == "study_toy"
    if launcher == "slurm":
        assert hl.gpus_per_node == 1 and hl.cpus_per_task == 8 and hl.mem_gb == 32 and hl.array_parallelism == 16
        assert list(hl.setup) == [] and hl.partition is None and hl.max_num_timeout == 0


def test_basic_and_joblib_launcher_overrides(tmp_path: Path) -> None:
    assert "hydra/launcher=basic" in launcher_overrides("basic", tmp_path, 1, "x")
    assert launcher_overrides("basic", tmp_path, 3, "x")[-2:] == ["hydra/launcher=joblib", "hydra.launcher.n_jobs=3"]


def test_run_task_survives_pickling_as_submitit_does() -> None:
    import cloudpickle

    task = RunTask(uri="sqlite:////x/mlflow.db", experiment_id="1", parent_run_id="p",
                   jobs=[JobInfo("baseline/easy/seed0", {"variant": "baseline"}, "abc", {"preset": "studio"})],
                   progress_path="/x/progress.jsonl", started_at=1.0, train_fn=fake_train, lease_s=30.0,
                   command="study run toy")
    for dumps, loads in ((pickle.dumps, pickle.loads), (cloudpickle.dumps, cloudpickle.loads)):
        back = loads(dumps(task))
        assert back == task and back.train_fn is fake_train


@pytest.mark.slow
def test_submitit_local_runs_the_study_with_the_same_metrics_as_basic(workdir: Path, mlflow_template: Path,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """Each run in its own submitit process (the fake trainer is found through PYTHONPATH)."""
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(HERE), os.environ.get("PYTHONPATH", "")]))
    sel = Selection(variants=["baseline", "cc"], seeds=2)
    kw = dict(studies_dir=TOY_STUDIES, train_fn=fake_train, generate=fake_generate, echo=lambda s: None)
    out = run_study("toy", sel, launcher="local", jobs=2, **kw)
    assert (out.launched, out.finished, out.failed) == (4, 4, 0)
    local = _finished()
    assert len(local) == 4
    store = open_store(_uri())
    pids = set()
    for rec in local.values():
        assert rec.tags["mlflow.parentRunId"] == out.parent_run_id
        assert len(store.client.get_metric_history(rec.run_id, "loss")) == LOSS_STEPS
        pids.add(rec.tags["lease.owner"])
        assert Path(rec.tags["out_dir"]).is_dir()
    assert len(pids) == 4 and str(os.getpid()) not in {p.split(":")[1] for p in pids}, "one process per run"
    sweep = Path(next(iter(local.values())).tags["out_dir"]).parents[2]
    assert list(sweep.glob(".submitit/*/*_result.pkl")), "submitit folder inside the study's sweep folder"

    prepare_workdir(workdir.parent / "basic", mlflow_template, monkeypatch)
    run_study("toy", sel, launcher="basic", **kw)
    basic = _finished()
    assert basic.keys() == local.keys()
    for key in basic:
        assert basic[key].metrics == local[key].metrics, key


def test_the_local_launcher_starts_a_job_as_one_ends_never_more_than_its_cap() -> None:
    alive, most, lock = [0], [0], threading.Lock()

    def launch_one(overrides: list[list[str]], initial_job_idx: int) -> list[str]:
        with lock:
            alive[0] += 1
            most[0] = max(most[0], alive[0])
        time.sleep(0.02 * (initial_job_idx % 3 + 1))  # jobs of different lengths
        with lock:
            alive[0] -= 1
        return [f"{initial_job_idx}:{overrides[0][0]}"]

    jobs = [[f"seed={i}"] for i in range(7)]
    assert _at_most(3, launch_one, jobs) == [f"{i}:seed={i}" for i in range(7)]  # in order
    assert most[0] == 3

    def dies(overrides: list[list[str]], initial_job_idx: int) -> list[str]:
        if initial_job_idx == 1:
            raise RuntimeError("job 1 died")  # as submitit raises for a job that did not return
        return launch_one(overrides, initial_job_idx)

    with pytest.raises(RuntimeError, match="job 1 died"):
        _at_most(2, dies, jobs)
    assert alive[0] == 0, "every other job ran to its end first"


def test_local_slots_are_one_per_core_as_memory_allows() -> None:
    assert local_slots(cores=2, available_gb=22.0) == 2
    assert local_slots(cores=16, available_gb=6.0) == 5  # 1.2 GB a run
    assert local_slots(cores=4, available_gb=0.5) == 1
    assert local_slots() >= 1


@pytest.mark.slow
def test_submitit_local_runs_at_most_jobs_trainers_at_once(workdir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """4 runs through the local launcher with ``jobs=2``: never more than 2 train at once, and 2 do."""
    spans = workdir / "spans.txt"
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(HERE), os.environ.get("PYTHONPATH", "")]))
    monkeypatch.setenv("FAKE_TRAIN_SLEEP", "3")
    monkeypatch.setenv("FAKE_TRAIN_SPANS", str(spans))
    out = run_study("toy", Selection(variants=["baseline"], seeds=4), launcher="local", jobs=2,
                    studies_dir=TOY_STUDIES, train_fn=fake_train, generate=fake_generate, echo=lambda s: None)
    assert (out.launched, out.finished, out.failed) == (4, 4, 0)
    # (time, +1 a start / -1 an end); sorted, an end comes before a start at the same instant
    events = sorted((float(t), d) for line in spans.read_text().splitlines() for t, d in zip(line.split(), (1, -1)))
    assert len(events) == 8
    alive, most = 0, 0
    for _, d in events:
        alive += d
        most = max(most, alive)
    assert most == 2


@pytest.mark.slow
def test_two_concurrent_invocations_on_sqlite_finish_each_run_exactly_once(workdir: Path) -> None:
    env = {**os.environ, "FAKE_TRAIN_SLEEP": "0.5", "PYTHONPATH": str(HERE)}
    args = [sys.executable, str(HERE / "drive_study.py"), "run", "toy", "--variants", "baseline,cc", "--seeds", "4"]
    procs = [subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
             for _ in range(2)]
    outs = [p.communicate(timeout=300)[0] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs
    runs = load_runs(open_store(_uri()), EXP, "toy")
    finished = Counter(r.key for r in runs if r.status == "FINISHED")
    assert len(finished) == 8 and set(finished.values()) == {1}, "every run FINISHED exactly once"
    assert all(r.status == "FINISHED" for r in runs), "no live run was failed by the other invocation"
    owners = {r.tags["lease.owner"].split(":")[1] for r in runs}
    assert owners <= {str(p.pid) for p in procs}
    parents = load_runs(open_store(_uri()), EXP, "toy", kind="study")
    n_done = sum(int(p.tags.get("n_finished", 0)) for p in parents)
    assert n_done == 8, outs
