"""A real one-node SLURM: ``study run secret5 --profile smoke --launcher slurm`` submits a job
array through Hydra's submitit launcher, every run finishes on the node, ``sacct`` lists the
jobs, and the report builds. Tracking goes to ``ftgspp-server`` (PostgreSQL): SLURM jobs do
not share a SQLite file."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from clusterlib import pg_server, slurm_cluster  # noqa: F401  (fixtures)

from harness.tracking.records import load_runs, open_store

BIN = Path(sys.executable).parent
# this test node has no GPU and little memory: ask for what it has
SITE = ["hydra.launcher.gpus_per_node=0", "hydra.launcher.cpus_per_task=1", "hydra.launcher.mem_gb=2",
        "hydra.launcher.timeout_min=20", "hydra.launcher.partition=debug"]


def test_smoke_study_runs_as_a_slurm_job_array(pg_server, slurm_cluster, tmp_path: Path) -> None:
    work = Path(slurm_cluster["root"]) / "work"  # on a path the job (and every node) can see
    work.mkdir()
    env = {**os.environ, "SLURM_CONF": slurm_cluster["conf"], "MLFLOW_TRACKING_URI": pg_server["uri"],
           "PATH": f"{BIN}:{os.environ['PATH']}:/usr/sbin"}
    run = subprocess.run([str(BIN / "study"), "run", "secret5", "--profile", "smoke", "--seeds", "2",
                          "--variants", "baseline,cc", "--launcher", "slurm", *SITE], cwd=work, env=env, capture_output=True, text=True,
                         timeout=900)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    assert "4 finished, 0 failed" in run.stdout, run.stdout[-3000:]

    runs = load_runs(open_store(pg_server["uri"]), "ftgspp/secret5", "secret5")
    assert len(runs) == 4 and {r.status for r in runs} == {"FINISHED"}
    for rec in runs:
        assert rec.tags["mlflow.source.type"] == "JOB", "the run ran inside a SLURM job"
        assert "--launcher slurm" in rec.tags["mlflow.source.name"]
    submitit = list(work.glob("outputs/studies/secret5/*/.submitit/*/*_result.pkl"))
    assert len(submitit) == 4, "submitit folder next to the sweep, one result per array task"

    sacct = subprocess.run(["sacct", "-c", "-n", "-P", "-o", "JobID,JobName,State"], env=env, capture_output=True,
                           text=True, timeout=60)
    assert sacct.returncode == 0, sacct.stderr
    jobs = [line.split("|") for line in sacct.stdout.splitlines() if "study_secret5" in line]
    print("sacct -c:\n" + sacct.stdout)
    assert len(jobs) == 4 and all(state == "COMPLETED" for _, _, state in jobs), sacct.stdout

    status = subprocess.run([str(BIN / "study"), "status", "secret5"], cwd=work, env=env, capture_output=True,
                            text=True, timeout=300)
    assert status.returncode == 0 and "total: 4 done, 0 failed, 0 missing" in status.stdout, status.stdout
    report = subprocess.run([str(BIN / "study"), "report", "secret5"], cwd=work, env=env, capture_output=True,
                            text=True, timeout=600)
    assert report.returncode == 0, report.stdout[-2000:] + report.stderr[-2000:]
    index = (work / "reports" / "secret5" / "index.md").read_text()
    assert "--launcher slurm" in index or "secret5" in index
