"""``study run``'s exit status tells the truth, with two real invocations of one study: a run
another live invocation holds is waited for (or, with ``--no-wait``, named with its holder and
lease expiry, exit status 3); a claim whose holder process is gone on this host is taken over at
once; and how ``run.completion`` sorts a plan into done, held and missing (exit 0, 3, 4).
"""

from __future__ import annotations

import re
import socket
import subprocess
import sys
import time
from pathlib import Path

from driven import Driven, at_gate, env, runs

from harness.run import completion, lease
from harness.tracking.records import RunRecord

ONE = ["run", "toy", "--variants", "baseline", "--seeds", "1"]


def _holder(workdir: Path) -> Driven:
    """An invocation holding baseline/easy/seed0 RUNNING at the gate."""
    holder = Driven("holder", ONE, env(workdir / "gate"))
    holder.until(lambda: at_gate() == 1, "the holder's run at its gate")
    return holder


def test_no_wait_exits_3_naming_the_holder_and_its_lease_expiry(workdir: Path) -> None:
    holder = _holder(workdir)
    other = Driven("other", [*ONE, "--no-wait"], env(workdir / "gate", gated_seeds=""))
    assert other.wait() == completion.EXIT_HELD == 3, other.stdout() + other.stderr()
    out = other.stdout()
    assert "0 already finished, 1 running elsewhere, 0 to run" in out
    (held,) = [line.strip() for line in out.splitlines() if line.strip().startswith("held: ")]
    assert f"held: baseline/easy/seed0 by host {socket.gethostname()}, pid {holder.pid} " in held
    expires_in = int(re.search(r"its lease expires at \d\d:\d\d:\d\d \(in (\d+)s\)", held).group(1))
    assert 0 < expires_in <= lease.DEFAULT_LEASE_S, held
    (workdir / "gate").touch()
    assert holder.wait() == 0
    assert [r.status for r in runs()] == ["FINISHED"], "the waiting invocation touched nothing"


def test_a_held_run_is_waited_for_and_then_counts_as_done(workdir: Path) -> None:
    holder = _holder(workdir)
    waiter = Driven("waiter", ONE, env(workdir / "gate", gated_seeds=""))
    waiter.until(lambda: "waiting for 1 run held by other invocations" in waiter.stdout(), "the waiter waiting")
    (workdir / "gate").touch()  # the holder finishes its run; the waiter sees it done
    assert holder.wait() == 0
    assert waiter.wait() == 0, waiter.stdout() + waiter.stderr()
    assert f"pid {holder.pid}" in waiter.stdout()
    assert "outputs:" not in waiter.stdout(), "the waiter launched nothing"
    assert [r.status for r in runs()] == ["FINISHED"]
    assert len(runs(kind="study")) == 1, "only the holder opened a parent run"


def test_a_waiting_invocation_runs_what_a_killed_holder_left(workdir: Path) -> None:
    holder = _holder(workdir)
    waiter = Driven("waiter", ONE, env(workdir / "gate", gated_seeds=""))
    waiter.until(lambda: "waiting for 1 run held by other invocations" in waiter.stdout(), "the waiter waiting")
    holder.proc.kill()  # SIGKILL: no chance to record anything; its claim stays RUNNING
    holder.wait()
    assert waiter.wait() == 0, waiter.stdout() + waiter.stderr()
    assert "1 of them ended without a result: running 1 here" in waiter.stdout()
    statuses = sorted(r.status for r in runs())
    assert statuses == ["FAILED", "FINISHED"]


def test_a_claim_whose_holder_process_is_gone_is_taken_over_at_once(workdir: Path) -> None:
    holder = _holder(workdir)
    holder.proc.kill()
    holder.wait()
    (orphan,) = runs()
    assert orphan.status == "RUNNING" and lease.heartbeat_age(orphan) < lease.DEFAULT_LEASE_S
    assert lease.holder_gone(orphan) and not lease.is_live(orphan)
    again = Driven("again", ONE, env(workdir / "gate", gated_seeds=""))  # the default 300 s lease
    assert again.wait() == 0, again.stdout() + again.stderr()
    assert "0 already finished, 1 to run" in again.stdout()
    by_id = {r.run_id: r for r in runs()}
    old, new = by_id[orphan.run_id], next(r for r in by_id.values() if r.run_id != orphan.run_id)
    assert old.status == "FAILED" and old.failure == "interrupted" and "holder gone" in old.error
    assert new.status == "FINISHED" and new.tags[lease.TOOK_OVER] == orphan.run_id


def _rec(run_id: str, seed: int, status: str, start: int, **tags: str) -> RunRecord:
    key = {"variant": "baseline", "scene": "easy", "seed": str(seed), "config_hash": "h"}
    return RunRecord(run_id, status, {**key, **tags}, start_time=start)


class _Planned:
    def __init__(self, seed: int) -> None:
        self.key = ("baseline", "easy", seed, "h")
        self.spec = type("Spec", (), {"label": f"baseline/easy/seed{seed}"})()


def test_settle_sorts_the_plan_into_done_held_and_missing() -> None:
    now = time.time()
    beat = {lease.HEARTBEAT: f"{now:.3f}", lease.SECONDS: "300"}
    elsewhere = {**beat, lease.OWNER: "node9:77"}
    gone = {**beat, lease.OWNER: f"{socket.gethostname()}:{_dead_pid()}"}
    existing = [
        _rec("a", 0, "FINISHED", 1),
        _rec("b", 1, "FAILED", 1, failure="crashed", error="RuntimeError: x"),  # an answer: done
        _rec("c", 2, "RUNNING", 1, **elsewhere),  # live elsewhere: held
        _rec("d", 3, "KILLED", 1, failure="interrupted", stop_signal="SIGTERM"),  # missing
        _rec("e", 4, "FINISHED", 1), _rec("f", 4, "KILLED", 2, failure="interrupted"),  # finished once: done
        _rec("g", 5, "RUNNING", 1, **gone),  # its holder is gone: missing
        _rec("h", 6, "FAILED", 1, failure="interrupted", error="lease expired"),  # taken over, no result: missing
    ]
    comp = completion.settle(existing, [_Planned(s) for s in range(8)], 300)
    assert comp.done == ["baseline/easy/seed0", "baseline/easy/seed1", "baseline/easy/seed4"]
    assert [r.run_id for r in comp.held] == ["c"]
    assert comp.missing == [f"baseline/easy/seed{s}" for s in (3, 5, 6, 7)]
    assert comp.exit_status == completion.EXIT_HELD
    comp.held.clear()
    assert comp.exit_status == completion.EXIT_INCOMPLETE
    comp.missing.clear()
    assert comp.exit_status == completion.EXIT_DONE == 0


def _dead_pid() -> int:
    """The pid of a process that has ended."""
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid
