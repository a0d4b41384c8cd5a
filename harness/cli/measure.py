"""``study measure NAME``: render speed and size of every finished run's trained model.

Training measures time and quality; how fast the trained model renders and how many bytes it
takes are measured afterwards, one model at a time, with nothing else running
(``ftgspp.bench.model_fps``). Each finished run of the study's latest invocation (or of the
selection given) that lacks them gets ``render_fps_1thread``, ``render_fps_all_cores``,
``render_cores`` and ``model_bytes`` logged to its MLflow run; ``--force`` measures again. A run
whose folder is gone (another machine's, or cleaned up) is skipped with a line that says so.
"""

from __future__ import annotations

import time
from pathlib import Path

from harness.tracking.mlflow_tracker import metric_entities

MEASURED = "render_fps_1thread"


def measure_study(name: str, sel=None, force: bool = False, echo=print) -> tuple[int, int]:
    """Measure the study's finished runs; returns (measured, skipped)."""
    from ftgspp.bench.model_fps import measure
    from harness.report.results import collect

    data = collect(name, sel)
    if data.store is None:
        return 0, 0
    done = [r for r in data.chosen.values() if r is not None and r.status == "FINISHED"]
    todo = [r for r in done if force or MEASURED not in r.metrics]
    echo(f"{name}: {len(done)} finished runs, {len(todo)} to measure (render FPS and model size)")
    measured = skipped = 0
    t0 = time.perf_counter()
    for k, rec in enumerate(todo, 1):
        out = Path(rec.tags.get("out_dir", ""))
        label = f"{rec.tags.get('variant')}/{rec.tags.get('scene')}/seed{rec.tags.get('seed')}"
        if not (out / "gaussians.pt").is_file():
            echo(f"  [{k}/{len(todo)}] {label}: skipped, no trained model at '{out}'")
            skipped += 1
            continue
        values = measure(out)
        data.store.log_batch(rec.run_id, metrics=metric_entities(values, 0))
        measured += 1
        echo(f"  [{k}/{len(todo)}] {label}: {values['render_fps_1thread']:.0f} FPS at 1 thread,"
             f" {values['render_fps_all_cores']:.0f} at {values['render_cores']:.0f},"
             f" {values['model_bytes'] / 1e6:.2f} MB ({time.perf_counter() - t0:.0f}s)")
    return measured, skipped
