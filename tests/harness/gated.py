"""A fake trainer that waits at a gate, and the ``study`` CLI around it, for stop and wait tests.

``gated_train`` is ``fakes.fake_train`` that, for a seed listed in ``$GATE_SEEDS`` (comma-separated;
unset: every seed), first logs one loss value, writes ``at_gate`` (its pid) into its output folder
and waits until the file ``$GATE_FILE`` exists (300 s at most, a safety net). Such a run stays
RUNNING in the tracking store for as long as a test keeps the gate shut.

    python gated.py run toy --seeds 3 ...   # `study` with the toy studies, fake scenes and gated_train

It is importable by name (``PYTHONPATH`` = this folder), so joblib and submitit workers unpickle
``gated_train`` by reference.
"""

from __future__ import annotations

import functools
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from fakes import fake_train  # noqa: E402

GATE_WAIT_S = 300.0


def gated_train(cfg, out_dir, tracker):  # (TrainConfig, Path, Tracker) -> RunResult, as fakes.fake_train
    seeds = os.environ.get("GATE_SEEDS")
    if seeds is None or str(cfg.seed) in seeds.split(","):
        tracker.log_metrics({"loss": 0.5}, step=0)  # something for the stop to flush
        (Path(out_dir) / "at_gate").write_text(str(os.getpid()))
        gate, deadline = Path(os.environ["GATE_FILE"]), time.monotonic() + GATE_WAIT_S
        try:
            while not gate.exists():
                if time.monotonic() > deadline:
                    raise RuntimeError("the gate never opened")
                time.sleep(0.05)
        except KeyboardInterrupt as exc:
            if os.environ.get("GATE_MANGLE"):
                raise SystemError("CPUDispatcher(<function k>) returned a result with an exception set") from exc
            raise
    return fake_train(cfg, out_dir, tracker)


if __name__ == "__main__":
    import pytest
    from conftest import use_fakes

    import gated  # by its module name, so that workers unpickle gated_train by reference
    import harness.run.runner

    mp = pytest.MonkeyPatch()
    use_fakes(mp)
    mp.setattr(harness.run.runner, "run_study", functools.partial(harness.run.runner.run_study,
                                                                  train_fn=gated.gated_train))
    from harness.cli.study import main

    raise SystemExit(main(sys.argv[1:]))
