"""What ``ftgspp check-gpu`` runs, and its bookkeeping: the overrides of its training runs, its bench
commands, and ``Check`` (the budget's clock, the summary lines, the children it started). Shared
by the real run (``check_gpu``) and the dry run (``gpu_dry_run``), which composes and parses the
same plan without a GPU.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

MODELS = ("ftgs", "stg")
PAPER_W, PAPER_H = 1352, 1014  # DyNeRF at half resolution, as the paper trains it
TRAIN_500K = ("676", "508")  # bench train at 500k: a quarter of DyNeRF (its scene is made in-process)
REPO = Path(__file__).resolve().parents[2]


def cpu_run_threads(cores: int | None = None) -> int:
    """Torch and Numba threads of each CPU quick run: a quarter of the cores (4 on the device's 16),
    so the two runs leave half the machine to gsplat's compile and runs."""
    return max(1, (cores or os.cpu_count() or 4) // 4)


def quick_overrides(scene: Path, model: str, backend: str, seed: int) -> list[str]:
    """``ftgspp train`` overrides of one quick run (``backend`` gsplat: on cuda; cpu: ``cpu_run_threads``
    torch threads, Numba's set by ``check_gpu.train_quick``)."""
    device = ["device=cuda"] if backend == "gsplat" else ["device=cpu", f"threads={cpu_run_threads()}"]
    return ["profile=quick", f"model={model}", f"data.path={scene}", f"backend={backend}", *device, f"seed={seed}"]


def paper_overrides(scene: Path) -> list[str]:
    """The paper-size run: stopped at the deadline, so no evaluation; progress logged every 10 steps;
    SIFT points filled to the 500k budget instead of the paper's dense matching (its CPU minutes at
    this resolution are not what the run measures)."""
    return ["profile=paper", "model=ftgspp", f"data.path={scene}", "backend=gsplat", "device=cuda", "seed=0",
            "init.matcher=sift", "eval_lpips=[alex]", "diagnostics=false", "log_every=10"]  # fmt: skip


def bench_commands() -> dict[str, list[str]]:
    """``ftgspp bench`` (or ``gpu_speed``) arguments of each bench step, by key."""
    return {
        "bench render 5k": ["bench", "render", "--n", "5000", "--no-compile-times", "--json"],
        "bench render 500k": ["render", "--n", "500000", "--width", str(PAPER_W), "--height", str(PAPER_H)],
        "bench train 5k": ["bench", "train", "--models", ",".join(MODELS), "--iterations", "50", "--json"],
        "bench train 500k": ["bench", "train", "--budget", "500000", "--backends", "gsplat", "--models", ",".join(MODELS),
                             "--width", TRAIN_500K[0], "--height", TRAIN_500K[1], "--iterations", "50",
                             "--repeats", "1", "--json"],
    }  # fmt: skip


def synth_args(out: Path, paper: bool) -> list[str]:
    size = ["--width", str(PAPER_W), "--height", str(PAPER_H)] if paper else []
    return ["synth", "--out", str(out), "--preset", "studio", "--seed", "0", *size]


class Check:
    """The run's clock, its summary lines and results, and where its files go."""

    def __init__(self, out: Path, budget: float, started: float) -> None:
        self.out, self.budget, self.started = out, budget, started
        self.work = Path(tempfile.mkdtemp(prefix="ftgspp-check-gpu-"))
        self.lines: list[str] = []
        self.results: dict[str, Any] = {}
        self.ok = True
        self.procs: list[subprocess.Popen] = []  # every child, ended by ``finish`` if still running
        self.closed = False  # set by ``finish``: no child starts after it

    def left(self) -> float:
        """Seconds left of the budget (infinite without one)."""
        return self.started + self.budget - time.time() if self.budget > 0 else float("inf")

    def fits(self, key: str, seconds: float) -> bool:
        """Whether ``seconds`` remain (with 15 s kept for the summary); else record the skip."""
        if self.left() - 15 >= seconds:
            return True
        self.record(key, f"{key}: SKIPPED: {self.left():.0f} s left of the {self.budget:.0f} s budget", None)
        return False

    def record(self, key: str, line: str, passed: bool | None, result: Any = None) -> None:
        """A summary line; ``passed`` None: a measurement, not a check."""
        self.lines.append(line)
        self.results[key] = {"line": line, "passed": passed, "result": result}
        self.ok &= passed is not False
        print(f"  {line}", flush=True)

    def step(self, text: str) -> None:
        """Print a step's heading with the seconds since the start."""
        print(f"[{time.time() - self.started:5.0f} s] {text}", flush=True)

    def timeout(self, cap: float) -> float:
        return max(1.0, min(cap, self.left() - 15))

    def start(self, cmd: list[str], log: str, env: dict[str, str] | None = None) -> subprocess.Popen:
        """Start ``cmd`` in the repository with its output in ``work/<log>`` (``env``: variables
        added to this process's environment)."""
        if self.closed:
            raise RuntimeError("the check has finished")
        with open(self.work / log, "w") as f:
            proc = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, cwd=REPO,
                                    env={**os.environ, **env} if env else None)
        self.procs.append(proc)
        return proc

    def run(self, cmd: list[str], log: str, cap: float, env: dict[str, str] | None = None) -> tuple[int, str]:
        """Run ``cmd`` for at most ``cap`` seconds (and the budget); (exit status, 124 on
        timeout; its output)."""
        proc = self.start(cmd, log, env)
        try:
            rc = proc.wait(timeout=self.timeout(cap))
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            rc = 124
        return rc, (self.work / log).read_text(errors="replace")


def _cmd(args: list[str], module: str = "harness.cli.ftgspp_cmd") -> list[str]:
    return [sys.executable, "-m", module, *args]


def json_line(text: str) -> dict[str, Any] | None:
    """The last line of ``text`` that parses as a JSON object."""
    for ln in reversed(text.splitlines()):
        if ln.startswith("{"):
            try:
                return json.loads(ln)
            except json.JSONDecodeError:
                continue
    return None


def tail(text: str, n: int = 3) -> str:
    return " | ".join(ln.strip() for ln in text.strip().splitlines()[-n:])
