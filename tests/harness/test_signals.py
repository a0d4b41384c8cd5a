"""A ``study run`` stopped by SIGTERM, SIGHUP or Ctrl-C (SIGINT), as a real process: every run of
the invocation is recorded (FINISHED, or KILLED with the signal), the parent run ends KILLED, no
claim or worker process is left, the last line is the command that resumes, and that command
runs exactly the missing runs. Through the basic launcher (the run in the study process),
joblib (worker processes) and submitit's local executor (a process per run), with the gated fake
trainer; and once end to end with the real trainer, whose training child flushes its curve.
"""

from __future__ import annotations

import json
import shlex
import signal
from collections import Counter
from pathlib import Path

import pytest
from driven import Driven, at_gate, env, loss_steps, no_processes_left, runs

TOY = ["run", "toy", "--variants", "baseline", "--seeds", "3"]
LAUNCHERS = {"basic": [], "joblib": ["--jobs", "2"], "local": ["--jobs", "2", "--launcher", "local"]}


def _resume_command(stdout: str, sig: signal.Signals) -> list[str]:
    """The command the last line names; checks the line."""
    last = stdout.strip().splitlines()[-1]
    assert last.startswith(f"stopped by {sig.name}: ") and "; resume with: study run " in last, stdout
    return shlex.split(last.split("resume with: ", 1)[1])


@pytest.mark.parametrize("launcher, name, mangled", [
    ("basic", "SIGTERM", False), ("joblib", "SIGTERM", False), ("local", "SIGTERM", False),
    ("basic", "SIGHUP", False), ("basic", "SIGINT", False),
    ("basic", "SIGTERM", True),  # the stop reaches the task as another error (through a Numba kernel)
])
def test_a_stop_signal_records_every_run_and_the_printed_command_resumes(launcher: str, name: str, mangled: bool,
                                                                         workdir: Path) -> None:
    sig = signal.Signals[name]
    parallel = launcher != "basic"
    gate = workdir / "gate"
    # seed 0 finishes; the gated seeds hold their runs RUNNING (in parallel two at once) until the signal
    extra = {"GATE_MANGLE": "1"} if mangled else {}
    study = Driven("first", [*TOY, *LAUNCHERS[launcher]], env(gate, "1,2" if parallel else "1", **extra))
    study.until(lambda: at_gate() == (2 if parallel else 1) and any(r.status == "FINISHED" for r in runs()),
                "the gated runs at their gate")
    study.proc.send_signal(sig)
    assert study.wait() == 128 + sig, study.stderr()
    command = _resume_command(study.stdout(), sig)
    assert command == ["study", *TOY, *LAUNCHERS[launcher]]
    assert "Traceback" not in study.stderr() and "KeyboardInterrupt" not in study.stderr(), study.stderr()

    by_seed = {r.tags["seed"]: r for r in runs()}
    assert by_seed["0"].status == "FINISHED"
    killed = sorted(seed for seed, r in by_seed.items() if r.status == "KILLED")
    assert killed == (["1", "2"] if parallel else ["1"]) and len(by_seed) == 1 + len(killed)
    for seed in killed:
        rec = by_seed[seed]
        assert (rec.failure, rec.tags["stop_signal"]) == ("interrupted", sig.name), rec.tags
        assert loss_steps(rec.run_id) == 1, "what the trainer logged before the stop was flushed"
    (parent,) = runs(kind="study")
    assert parent.status == "KILLED" and parent.tags["stop_signal"] == sig.name
    assert (parent.tags["n_finished"], parent.tags["n_killed"]) == ("1", str(len(killed)))
    assert no_processes_left(workdir) == [], "every worker and training process has ended"

    gate.touch()
    again = Driven("again", command[1:], env(gate))
    assert again.wait() == 0, again.stdout() + again.stderr()
    assert "1 already finished, 2 to run" in again.stdout()
    after = runs()
    finished = Counter(r.key for r in after if r.status == "FINISHED")
    assert len(finished) == 3 and set(finished.values()) == {1}, "every run exactly once"
    assert sorted(r.tags["seed"] for r in after if r.status == "KILLED") == killed, "the record of the stop stays"
    assert all(r.status != "RUNNING" for r in after)


@pytest.mark.slow
def test_sigterm_stops_a_real_training_whose_child_flushes_its_curve(workdir: Path) -> None:
    """The secret5 smoke study with the real trainer (portable mode: each run trains in a child
    process, ftgspp.runtime.child), stopped while seed 1 trains; the re-run trains only seed 1."""
    args = ["run", "secret5", "--profile", "smoke", "--variants", "baseline", "--seeds", "2", "iterations=300"]
    study = Driven("first", args, env(workdir / "gate"), module="harness.cli.study")
    seed1 = lambda: list(Path("outputs/studies").glob("secret5/*/baseline/studio/seed1"))  # noqa: E731
    # the child's first checkpoint (iteration 20 of 300; the smoke profile logs the loss every 10)
    study.until(lambda: any((p / "checkpoint.pt").is_file() for p in seed1()), "seed 1 training")
    study.proc.send_signal(signal.SIGTERM)
    assert study.wait() == 143, study.stderr()[-3000:]
    command = _resume_command(study.stdout(), signal.SIGTERM)
    assert command == ["study", *args]
    assert "Traceback" not in study.stderr()

    by_seed = {r.tags["seed"]: r for r in runs("secret5")}
    assert by_seed["0"].status == "FINISHED"
    stopped = by_seed["1"]
    assert stopped.status == "KILLED" and stopped.tags["stop_signal"] == "SIGTERM"
    assert json.loads((seed1()[0] / "dispatch_result.json").read_text())["stopped"] == "SIGTERM"
    assert loss_steps(stopped.run_id) >= 1, "the training child's curve so far is in the store"
    assert runs("secret5", kind="study")[0].status == "KILLED"
    assert no_processes_left(workdir) == [], "the training child has ended too"

    again = Driven("again", command[1:], env(workdir / "gate"), module="harness.cli.study")
    assert again.wait() == 0, again.stdout()[-3000:] + again.stderr()[-3000:]
    assert "1 already finished, 1 to run" in again.stdout()
    finished = Counter(r.tags["seed"] for r in runs("secret5") if r.status == "FINISHED")
    assert finished == {"0": 1, "1": 1}


def test_ctrl_c_while_the_invocation_plans_is_the_same_one_line(fakes_on: None, monkeypatch: pytest.MonkeyPatch,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    from harness.cli.study import main

    def interrupted(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt  # Ctrl-C before the runner's own handlers were on

    monkeypatch.setattr("harness.run.runner.run_study", interrupted)
    assert main(["run", "toy", "--seeds", "1"]) == 130
    captured = capsys.readouterr()
    assert captured.out.strip().splitlines() == ["stopped by SIGINT: 0 runs finished, 0 recorded KILLED"
                                                 " (stop_signal=SIGINT); resume with: study run toy --seeds 1"]
    assert captured.err == ""
