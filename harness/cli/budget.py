"""``study budget``: find the smallest Gaussian budget a scene needs, as a tracked study.

Starting at ``start`` Gaussians, the budget doubles while doubling still gains at least
``threshold`` dB of held-out PSNR (mean over ``seeds`` runs; ``analysis.budget_search.gain``), then
bisects between the last budget that was not enough and the first that was, judging each
against the largest budget tried. Every run is an ordinary study run (MLflow experiment
``ftgspp/budget_<scene>``, resumable, one variant ``b<N>`` per budget), so a second search on
the same scene reuses what the first trained. The result names the smallest sufficient
budget, its gap to the largest budget tried with a 95% interval, and the training time it saves.

    study budget --preset static              # a built-in synthetic scene
    study budget --data /data/my_scene --max 64000 model=ftgspp
    study budget --preset plain --metric psnr_cc   # judge the colour-aligned PSNR
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ftgspp.errors import InputError
from harness.analysis import budget_search as B
from harness.analysis.budget_search import BudgetSearch
from harness.run.runner import run_study
from harness.spec.plan import plan_runs
from harness.spec.runs import Selection, expand
from harness.spec.study_schema import SYNTH_ROOT, ProfileSpec, StudyScene, StudySpec, TableSpec
from harness.tracking.records import load_runs, open_store, tracking_target


def study_for(name: str, scene: StudyScene, budgets: list[int], seeds: int, overrides: list[str], jobs: int,
              metric: str = "psnr") -> StudySpec:
    """A study with one variant per budget tried, on one scene (the quick profile's settings)."""
    variants = {f"b{b}": (f"budget={b}",) for b in sorted(budgets)}
    first = next(iter(variants))
    prof = ProfileSpec("quick", seeds, ("profile=quick", *overrides), (scene,), variants, baseline=first, jobs=jobs)
    return StudySpec(name, f"The smallest Gaussian budget scene {scene.name} needs.", first, 0, (metric,),
                     TableSpec(), (), (), {"quick": prof})


def synthetic_scene(preset: str) -> StudyScene:
    """A built-in synthetic scene (generated on demand into data/synth/budget_<preset>)."""
    return StudyScene(f"budget_{preset}", {"preset": preset, "seed": 0, "layout": "dynerf"},
                      synth_dir=(SYNTH_ROOT / f"budget_{preset}").as_posix())


def data_scene(path: str) -> StudyScene:
    """A scene folder of the user's."""
    from pathlib import Path

    return StudyScene(Path(path).name or "scene", overrides=(f"data.path={path}",))


def search(scene: StudyScene, *, start: int = 500, max_budget: int = 64_000, threshold: float = 0.1,
           seeds: int = 3, overrides: list[str] | None = None, jobs: int = 1, metric: str = "psnr",
           echo: Callable[[str], None] = print, **run_kw: object) -> BudgetSearch:
    """Double, then bisect (module docstring); every budget is trained through ``run_study``.
    ``metric``: the PSNR judged (``analysis.budget_search.METRICS``); the runs are the same for both."""
    if metric not in B.METRICS:
        raise InputError("--metric", f"unknown '{metric}' (known: {', '.join(B.METRICS)})")
    name = f"budget_{scene.name}"
    found = BudgetSearch(scene.name, threshold, metric)
    overrides = list(overrides or [])

    def measure(budget: int) -> np.ndarray:
        if budget not in found.scores:
            budgets = sorted({*found.scores, budget})
            spec = study_for(name, scene, budgets, seeds, overrides, jobs, metric)
            sel = Selection(variants=[f"b{budget}"])
            run_study(name, sel, jobs=jobs, echo=echo, study=spec, **run_kw)
            _read(found, spec, sel, budget)
        return np.array(found.scores[budget])

    low, high = None, start
    measure(high)
    while True:
        nxt = high * 2
        if nxt > max_budget:
            found.steps.append(f"{nxt} would exceed --max {max_budget}: no saturation up to {high}")
            found.chosen, found.saturated = high, False
            return found
        g = B.gain(measure(high), measure(nxt))
        found.steps.append(f"{high} -> {nxt}: {g.mean:+.3f} dB [{g.low:+.3f}, {g.high:+.3f}]")
        if g.mean < threshold:
            break
        low, high = high, nxt
    found.saturated = True
    top = high * 2
    best = measure(top)
    lo = low if low is not None else max(high // 2, 1)
    while high - lo > max(high // 8, 100):  # bisect: about an eighth of the budget
        mid = B.midpoint(lo, high)
        if mid in (lo, high):
            break
        ok = B.sufficient(measure(mid), best, threshold)
        found.steps.append(f"{mid}: {np.mean(best) - np.mean(found.scores[mid]):+.3f} dB below {top}"
                           f" -> {'enough' if ok else 'not enough'}")
        lo, high = (lo, mid) if ok else (mid, high)
    found.chosen = high
    return found


def _read(found: BudgetSearch, spec: StudySpec, sel: Selection, budget: int) -> None:
    """The finished runs of ``budget`` from the store (latest per seed)."""
    planned = plan_runs(expand(spec, sel))
    uri, exp = tracking_target(sel.overrides, planned[0].params, spec.name)
    keys = {p.key for p in planned}
    latest: dict[tuple, object] = {}
    for rec in load_runs(open_store(uri), exp, spec.name):
        if rec.key in keys and rec.status == "FINISHED":
            latest[rec.key] = rec
    found.scores[budget] = [r.metrics[found.metric] for r in latest.values() if found.metric in r.metrics]
    found.seconds[budget] = [r.metrics.get("train_seconds", np.nan) for r in latest.values()]
    found.faded[budget] = [r.metrics.get("n_faded", np.nan) for r in latest.values()]
    found.trainers |= {r.tags["trainer_fingerprint"] for r in latest.values() if r.tags.get("trainer_fingerprint")}
    if len(found.scores[budget]) == 0:
        raise InputError(f"budget {budget}", f"no run finished (their errors: MLflow experiment ftgspp/{spec.name})")
