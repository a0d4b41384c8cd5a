"""The ``study`` command line: listing and one-line exit-2 errors that write nothing."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from harness.cli.study import main
from harness.tracking.records import load_runs, open_store


def _err_lines(capsys: pytest.CaptureFixture[str]) -> list[str]:
    return [line for line in capsys.readouterr().err.splitlines() if line.strip()]


def _store_is_untouched() -> None:
    store = open_store(f"sqlite:///{Path('mlflow.db').resolve()}")
    assert store is not None
    assert store.experiment_id("ftgspp/toy", create=False) is None
    assert load_runs(store, "ftgspp/toy", "toy") == []


def test_list_names_every_study_with_run_counts(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for name in ("secret1", "secret5", "lpips", "ablation", "speed_accuracy", "stability"):
        assert f"{name}: " in out
    from harness.spec.runs import Selection, expand
    from harness.spec.study_files import load_study

    n = len(expand(load_study("secret5"), Selection(profile="quick")))
    assert f"quick: {n} runs = 5 variants x 1 scene x 5 seeds" in out  # what `study run` would plan


def test_unknown_study_is_one_line_exit_2_and_creates_no_store(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    for cmd in (["run", "nosuch"], ["status", "nosuch"], ["report", "nosuch"]):
        with pytest.raises(SystemExit) as exc:
            main(cmd)
        assert exc.value.code == 2
        lines = _err_lines(capsys)
        assert len(lines) == 1 and "unknown study" in lines[0] and "secret5" in lines[0]
    assert not (tmp_path / "mlflow.db").exists() and not (tmp_path / "reports").exists()


@pytest.mark.parametrize(
    "args, words",
    [
        (["--variants", "nope"], "unknown variant"),
        (["--scenes", "nope"], "unknown scene"),
        (["iterations=lots"], "iterations"),
        (["model.nosuch=1"], "nosuch"),
        (["model.gate=[1"], "malformed override"),
        (["notanoverride"], "key=value"),
        (["--seeds", "0"], "--seeds"),
    ],
)
def test_bad_input_is_one_line_exit_2_and_writes_nothing(args: list[str], words: str, workdir: Path, fakes_on: None,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["run", "toy", *args])
    assert exc.value.code == 2
    lines = _err_lines(capsys)
    assert len(lines) == 1 and words in lines[0], lines
    _store_is_untouched()
    assert not Path("outputs").exists() and not Path("data").exists()


def test_unreachable_tracking_server_is_one_line_exit_2(workdir: Path, fakes_on: None,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(SystemExit) as exc:
        main(["run", "toy", f"tracking.uri=http://127.0.0.1:{port}"])
    assert exc.value.code == 2
    lines = _err_lines(capsys)
    assert len(lines) == 1 and "cannot reach an MLflow server" in lines[0]
    _store_is_untouched()


def test_usage_errors_are_one_line_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    for argv in ([], ["frobnicate"], ["run"], ["run", "secret5", "--jobs", "two"]):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2
        assert len(_err_lines(capsys)) == 1


def test_status_and_report_of_a_study_never_run_write_no_store(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                               fakes_on: None, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    assert main(["status", "toy"]) == 0
    assert "total: 0 done, 0 failed, 8 missing" in capsys.readouterr().out
    for argv in (["report", "toy"], ["report", "toy", "--out", "reports"]):  # never an empty report over one
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2
        lines = _err_lines(capsys)
        assert len(lines) == 1 and "no finished runs" in lines[0] and "nothing written" in lines[0]
    assert not (tmp_path / "mlflow.db").exists()
    assert not (tmp_path / "outputs").exists() and not (tmp_path / "reports").exists()


def test_overrides_may_follow_options(monkeypatch: pytest.MonkeyPatch) -> None:
    seen = {}
    monkeypatch.setattr("harness.run.runner.run_study", lambda name, sel, jobs, **kw: seen.update(sel=sel, jobs=jobs, **kw))
    assert main(["run", "secret5", "a=1", "--variants", "cc", "b=2", "--jobs", "2", "c=3"]) == 0
    assert seen["sel"].overrides == ["a=1", "b=2", "c=3"] and seen["sel"].variants == ["cc"] and seen["jobs"] == 2
    assert seen["launcher"] == "basic" and seen["lease_s"] is None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _fake_sbatch(folder: Path) -> str:
    sbatch = folder / "sbatch"
    sbatch.write_text("#!/bin/sh\necho 'sbatch must not be called' >&2\nexit 1\n")
    sbatch.chmod(0o755)
    return str(folder)


@pytest.mark.parametrize("case", ["unknown_launcher", "no_sbatch", "slurm_sqlite", "db_refused", "bad_lease",
                                  "bad_launcher_key", "launcher_key_for_basic"])
def test_scale_out_bad_input_is_one_line_exit_2_and_writes_nothing(case: str, workdir: Path, fakes_on: None,
                                                                   monkeypatch: pytest.MonkeyPatch,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    bin_dir = workdir.parent / "bin"
    bin_dir.mkdir()
    args, words = {
        "unknown_launcher": (["--launcher", "ray"], "invalid choice: 'ray'"),
        "no_sbatch": (["--launcher", "slurm"], "sbatch not found on PATH"),
        "slurm_sqlite": (["--launcher", "slurm"], "make server"),
        "db_refused": ([f"tracking.uri=postgresql+psycopg://me:secret@127.0.0.1:{_free_port()}/mlflow"],
                       "database refused the connection"),
        "bad_lease": (["--lease", "0"], "--lease"),
        "bad_launcher_key": (["--launcher", "local", "hydra.launcher.gpus=1"], "not valid for --launcher local"),
        "launcher_key_for_basic": (["hydra.launcher.timeout_min=5"], "not valid for --launcher basic"),
    }[case]
    path = bin_dir.as_posix() if case == "no_sbatch" else f"{_fake_sbatch(bin_dir)}:{Path('/usr/bin')}"
    monkeypatch.setenv("PATH", path)
    with pytest.raises(SystemExit) as exc:
        main(["run", "toy", *args])
    assert exc.value.code == 2
    lines = _err_lines(capsys)
    assert len(lines) == 1 and words in lines[0], lines
    assert "secret" not in lines[0], "no password in error lines"
    _store_is_untouched()
    assert not Path("outputs").exists() and not Path("data").exists()
