"""Leases against a real SQLite store: claim, skip live claims, take over stale ones, races."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest

from harness.run import lease
from harness.tracking.records import RunRecord, find_key_runs
from harness.tracking.store import Store

KEY = {"study": "toy", "variant": "baseline", "scene": "easy", "seed": "0", "config_hash": "abc123", "kind": "run"}


@pytest.fixture
def store(workdir: Path) -> Store:
    return Store(f"sqlite:///{Path('mlflow.db').resolve()}")


@pytest.fixture
def exp(store: Store) -> str:
    exp_id = store.experiment_id("ftgspp/toy")
    assert exp_id is not None
    return exp_id


def _runs(store: Store, exp: str) -> dict[str, RunRecord]:
    return {r.run_id: r for r in find_key_runs(store, exp, KEY)}


def test_age_and_liveness_follow_the_runs_own_lease() -> None:
    now = 1_000_000.0
    rec = RunRecord("r", "RUNNING", {lease.HEARTBEAT: str(now - 50), lease.SECONDS: "60"}, start_time=0)
    assert lease.heartbeat_age(rec, now) == pytest.approx(50)
    assert lease.is_live(rec, default_lease_s=10, now=now)  # its own 60 s lease counts, not the caller's
    assert not lease.is_live(rec, now=now + 11)
    old = RunRecord("o", "RUNNING", {}, start_time=int((now - 100) * 1000))  # from before leases
    assert lease.heartbeat_age(old, now) == pytest.approx(100)
    assert lease.is_live(old, default_lease_s=300, now=now) and not lease.is_live(old, default_lease_s=30, now=now)
    assert not lease.is_live(RunRecord("f", "FINISHED", {lease.HEARTBEAT: str(now)}), now=now)


def test_claim_then_a_second_claimer_skips_the_live_run(store: Store, exp: str) -> None:
    first = lease.acquire(store, exp, "baseline/easy/seed0", KEY, lease_s=60, owner="nodeA:1")
    assert first.run_id is not None and not first.took_over
    rec = _runs(store, exp)[first.run_id]
    assert rec.status == "RUNNING" and rec.tags[lease.OWNER] == "nodeA:1" and rec.tags[lease.SECONDS] == "60"
    second = lease.acquire(store, exp, "baseline/easy/seed0", KEY, lease_s=60, owner="nodeB:2")
    assert second.run_id is None and "nodeA:1" in second.reason
    assert [r.status for r in _runs(store, exp).values()] == ["RUNNING"], "the live claim was left alone"


def test_stale_claim_is_failed_and_taken_over(store: Store, exp: str) -> None:
    old = store.create_run(exp, "old", {**KEY, lease.OWNER: "nodeA:1", lease.SECONDS: "5",
                                        lease.HEARTBEAT: str(time.time() - 6)})
    claim = lease.acquire(store, exp, "baseline/easy/seed0", KEY, lease_s=5, owner="nodeB:2")
    assert claim.run_id is not None and claim.took_over == (old,)
    runs = _runs(store, exp)
    assert runs[old].status == "FAILED" and runs[old].failure == "interrupted"
    assert "lease expired" in runs[old].error and "nodeA:1" in runs[old].error and "nodeB:2" in runs[old].error
    assert runs[claim.run_id].tags[lease.TOOK_OVER] == old


def test_finished_run_is_never_claimed_again(store: Store, exp: str) -> None:
    done = store.create_run(exp, "done", dict(KEY))
    store.terminate(done, "FINISHED")
    assert lease.acquire(store, exp, "x", KEY, lease_s=5) == lease.Claim(None, "finished")
    assert list(_runs(store, exp)) == [done]


def test_simultaneous_claimers_let_exactly_one_through(store: Store, exp: str) -> None:
    """Eight claimers released at once (threads, each with its own client): one claim survives."""
    uri = store.uri
    gate = threading.Barrier(8)
    claims: list[lease.Claim] = []

    def claimer(i: int) -> None:
        mine = Store(uri)
        gate.wait()
        claims.append(lease.acquire(mine, exp, "baseline/easy/seed0", KEY, lease_s=60, owner=f"w{i}"))

    threads = [threading.Thread(target=claimer, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    winners = [c for c in claims if c.run_id is not None]
    assert len(claims) == 8 and len(winners) == 1
    assert list(_runs(store, exp)) == [winners[0].run_id], "withdrawn claims are gone from searches"


def test_heartbeat_refreshes_and_notices_a_takeover(store: Store, exp: str) -> None:
    claim = lease.acquire(store, exp, "x", KEY, lease_s=0.25)
    assert claim.run_id is not None
    first = float(_runs(store, exp)[claim.run_id].tags[lease.HEARTBEAT])
    with lease.Heartbeat(store, claim.run_id, lease_s=0.25) as beat:
        while float(_runs(store, exp)[claim.run_id].tags[lease.HEARTBEAT]) == first:
            time.sleep(0.02)
        store.terminate(claim.run_id, "FAILED", {"failure": "interrupted"})  # as a taker would
        while not beat.lost:
            time.sleep(0.02)
    assert _runs(store, exp)[claim.run_id].status == "FAILED"


def test_lease_length_comes_from_the_option_or_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(lease.ENV_LEASE_S, raising=False)
    assert lease.lease_seconds() == lease.DEFAULT_LEASE_S
    monkeypatch.setenv(lease.ENV_LEASE_S, "42")
    assert lease.lease_seconds() == 42 and lease.lease_seconds(7) == 7
    with pytest.raises(ValueError):
        lease.lease_seconds(0)



def test_status_lists_running_claims_with_host_and_age(workdir: Path, fakes_on: None, store: Store, exp: str,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    from harness.cli.study import main

    assert main(["run", "toy", "--variants", "baseline", "--seeds", "1"]) == 0
    other = {**KEY, "seed": "1", "config_hash": "feed01"}
    store.create_run(exp, "baseline/easy/seed1", {**other, lease.OWNER: "node7:4242", lease.SECONDS: "300",
                                                  lease.HEARTBEAT: str(time.time() - 12)})
    store.create_run(exp, "cc/easy/seed1", {**other, "variant": "cc", lease.OWNER: "node8:1",
                                            lease.SECONDS: "300", lease.HEARTBEAT: str(time.time() - 900)})
    capsys.readouterr()
    assert main(["status", "toy", "--variants", "baseline", "--seeds", "1"]) == 0
    out = capsys.readouterr().out
    assert "running: baseline/easy/seed1 on node7:4242" in out and "(live)" in out
    assert "running: cc/easy/seed1 on node8:1" in out and "stale: the next `study run` takes it over" in out
    assert "total: 1 done, 0 failed, 0 missing" in out


def test_a_worker_whose_run_was_taken_over_does_not_finish_it(workdir: Path) -> None:
    """A worker silent past its lease (suspended, partitioned) finds its run FAILED by a taker:
    it must not flip it to FINISHED, or the key would end FINISHED twice."""
    from conftest import TOY_STUDIES
    from fakes import fake_generate, fake_train

    from harness.run.runner import run_study
    from harness.spec.runs import Selection

    def taken_over_midway(cfg, out_dir, tracker):
        tracker.store.terminate(tracker.run_id, "FAILED", {"failure": "interrupted", "error": "lease expired"})
        return fake_train(cfg, out_dir, tracker)

    out = run_study("toy", Selection(variants=["baseline"], seeds=1), studies_dir=TOY_STUDIES,
                    train_fn=taken_over_midway, generate=fake_generate, echo=lambda s: None)
    assert (out.finished, out.failed) == (0, 1) and out.results[0]["status"] == "LOST"
    store = Store(f"sqlite:///{Path('mlflow.db').resolve()}")
    (rec,) = [r for r in store.search(store.experiment_id("ftgspp/toy"), "tags.kind = 'run'")]
    assert rec.info.status == "FAILED" and rec.data.tags["failure"] == "interrupted"


def test_run_study_leaves_live_claims_to_their_owner(workdir: Path, store: Store, exp: str) -> None:
    from conftest import TOY_STUDIES
    from fakes import fake_generate, fake_train

    from harness.run.runner import run_study
    from harness.spec.plan import plan_runs
    from harness.spec.runs import Selection, expand
    from harness.spec.study_files import load_study

    sel = Selection(variants=["baseline"], seeds=2)
    seed1 = next(p for p in plan_runs(expand(load_study("toy", TOY_STUDIES), sel)) if p.spec.seed == 1)
    live = store.create_run(exp, seed1.spec.label, {**seed1.tags, "kind": "run", lease.OWNER: "node9:77",
                                                    lease.SECONDS: "300", lease.HEARTBEAT: str(time.time())})
    lines: list[str] = []
    out = run_study("toy", sel, studies_dir=TOY_STUDIES, train_fn=fake_train, generate=fake_generate,
                    echo=lines.append)
    assert (out.launched, out.finished) == (1, 1)
    assert "0 already finished, 1 running elsewhere, 1 to run" in lines[0]
    assert "running elsewhere: baseline/easy/seed1 (node9:77, heartbeat" in lines[1]
    assert store.status(live) == "RUNNING", "a live claim of another invocation is never touched"
