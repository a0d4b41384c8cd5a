"""``study budget``: find the smallest Gaussian budget a scene needs, as a tracked study.

The smallest model is the fewest Gaussians whose held-out PSNR is within the SESOI (0.2 dB,
docs/sesoi.md) of the best model trained for the scene, settled by the interval over seeds
(``analysis.budget_search``: doubling from ``start`` until a doubling's gain is equivalent to
zero within ±SESOI, then bisecting down to the smallest budget whose gap to the best is bounded
below the SESOI; at ``--max`` unsettled it names the runs per budget that would settle it).
Every run is an ordinary study run (MLflow experiment ``ftgspp/budget_<scene>``, resumable, one
variant ``b<N>`` per budget), so a second search on the same scene reuses what the first
trained. The answer names the smallest sufficient budget, its gap to the best with its
interval, the Gaussians it draws (``n_alive``), its model bytes and the training time it saves.

    study budget --preset static              # a built-in synthetic scene
    study budget --preset known_size          # K = 500 Gaussians and sensor noise of SD 2 (8-bit)
    study budget --preset known_size --noise-sd 0    # the noise-free scene (budget_known_size)
    study budget --data /data/my_scene --max 64000 model=ftgspp
    study budget --preset plain --metric psnr_cc   # judge the colour-aligned PSNR

On the known-size scene ``--control`` also trains K Gaussians started from the scene's true ones
(``init.matcher=known``, ftgspp/init/known.py): what the optimiser reaches at K from the answer.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ftgspp.errors import InputError
from harness.analysis import budget_search as B
from harness.analysis.budget_search import BudgetSearch
from harness.run.runner import run_study
from harness.spec.known_scene import PRESET as KNOWN_SIZE
from harness.spec.metrics import sesoi as metric_sesoi
from harness.spec.plan import plan_runs
from harness.spec.runs import Selection, expand
from harness.spec.study_schema import SYNTH_ROOT, ProfileSpec, StudyScene, StudySpec, TableSpec
from harness.tracking.records import RunRecord, load_runs, open_store, tracking_target

NOISE_SD = 2.0  # the budget study's known-size scene: sensor noise SD in 8-bit units (≈ 42 dB ceiling)
CONTROL_VARIANT = "control"
# the control's init: the true Gaussians, perturbed (ftgspp/init/known.py), visible over the whole
# 1-s clip (a temporal SD of 1 s; the default 0.1 s would hide them away from the clip's middle), at
# the true opacities' mean (they are drawn from U(0.75, 0.95))
CONTROL = ("init.matcher=known", "init.duration=1.0", "init.opacity=0.85")


def study_for(name: str, scene: StudyScene, budgets: list[int], seeds: int, overrides: list[str], jobs: int,
              metric: str = "psnr", control: int | None = None) -> StudySpec:
    """A study with one variant per budget tried, on one scene (the quick profile's settings), and
    the control (``control`` Gaussians from the truth) when asked."""
    variants = {f"b{b}": (f"budget={b}",) for b in sorted(budgets)}
    if control:
        variants[CONTROL_VARIANT] = (f"budget={control}", *CONTROL)
    first = next(iter(variants))
    prof = ProfileSpec("quick", seeds, ("profile=quick", *overrides), (scene,), variants, baseline=first, jobs=jobs)
    return StudySpec(name, f"The smallest Gaussian budget scene {scene.name} needs.", first, 0, (metric,),
                     TableSpec(), (), (), {"quick": prof})


def synthetic_scene(preset: str, noise_sd: float | None = None) -> StudyScene:
    """A built-in synthetic scene (generated on demand into data/synth/budget_<name>). The known-size
    scene carries sensor noise of SD ``noise_sd`` (default ``NOISE_SD``; its name says it,
    ``budget_known_size_noise2``); at 0 it is the noise-free scene of the committed runs, with the
    arguments and the name it had (``budget_known_size``), so their config hashes hold."""
    args = {"preset": preset, "seed": 0, "layout": "dynerf"}
    name = f"budget_{preset}"
    if preset == KNOWN_SIZE:
        sd = NOISE_SD if noise_sd is None else float(noise_sd)
        if sd:
            args["noise_sd"] = sd
            name += f"_noise{sd:g}".replace(".", "p")
    elif noise_sd:
        raise InputError("--noise-sd", f"only the {KNOWN_SIZE} scene takes sensor noise, not '{preset}'")
    return StudyScene(name, args, synth_dir=(SYNTH_ROOT / name).as_posix())


def data_scene(path: str) -> StudyScene:
    """A scene folder of the user's."""
    from pathlib import Path

    return StudyScene(Path(path).name or "scene", overrides=(f"data.path={path}",))


def search(scene: StudyScene, *, start: int = 500, max_budget: int = 64_000, sesoi: float | None = None,
           seeds: int = 3, overrides: list[str] | None = None, jobs: int = 1, metric: str = "psnr",
           control: int | None = None, echo: Callable[[str], None] = print, **run_kw: object) -> BudgetSearch:
    """Double, then bisect (``analysis.budget_search.find``); every budget is trained through
    ``run_study``. ``metric``: the PSNR judged (``analysis.budget_search.METRICS``; the runs are the
    same for both); ``sesoi``: dB within the best that count as as good (default: the metric's
    SESOI, docs/sesoi.md); ``control``: also train that many Gaussians started from the known-size
    scene's true ones (``CONTROL``), shown beside the search."""
    if metric not in B.METRICS:
        raise InputError("--metric", f"unknown '{metric}' (known: {', '.join(B.METRICS)})")
    name = f"budget_{scene.name}"
    found = BudgetSearch(scene.name, sesoi if sesoi is not None else metric_sesoi(metric)[0], metric)
    overrides = list(overrides or [])
    tried: set[int] = set()

    def train(budgets: list[int], variant: str) -> list[RunRecord]:
        spec = study_for(name, scene, budgets, seeds, overrides, jobs, metric, control)
        sel = Selection(variants=[variant])
        run_study(name, sel, jobs=jobs, echo=echo, study=spec, **run_kw)
        return _finished(spec, sel)

    def measure(budget: int) -> np.ndarray:
        if budget not in found.scores:
            tried.add(budget)
            _read(found, budget, train(sorted(tried), f"b{budget}"), f"budget {budget}")
        return np.array(found.scores[budget])

    B.find(found, measure, start, max_budget)
    if control:
        runs = train(sorted(tried), CONTROL_VARIANT)
        found.control = [r.metrics[metric] for r in runs if metric in r.metrics]
    return found


def _finished(spec: StudySpec, sel: Selection) -> list[RunRecord]:
    """The finished runs of the selection from the store (the latest per seed)."""
    planned = plan_runs(expand(spec, sel))
    uri, exp = tracking_target(sel.overrides, planned[0].params, spec.name)
    keys = {p.key for p in planned}
    latest: dict[tuple, RunRecord] = {}
    for rec in load_runs(open_store(uri), exp, spec.name):
        if rec.key in keys and rec.status == "FINISHED":
            latest[rec.key] = rec
    return list(latest.values())


def _model_bytes(rec: RunRecord) -> float:
    """The trained model's bytes: ``study measure``'s metric, else its files in the run's folder."""
    from pathlib import Path

    from ftgspp.bench.model_fps import model_bytes

    if "model_bytes" in rec.metrics:
        return rec.metrics["model_bytes"]
    out = Path(rec.tags.get("out_dir", ""))
    size = model_bytes(out) if rec.tags.get("out_dir") and out.is_dir() else 0
    return float(size) if size else np.nan


def _read(found: BudgetSearch, budget: int, runs: list[RunRecord], what: str) -> None:
    """The values of ``budget``'s finished runs into ``found``."""
    found.scores[budget] = [r.metrics[found.metric] for r in runs if found.metric in r.metrics]
    found.seconds[budget] = [r.metrics.get("train_seconds", np.nan) for r in runs]
    found.faded[budget] = [r.metrics.get("n_faded", np.nan) for r in runs]
    found.alive[budget] = [r.metrics.get("n_gaussians", np.nan) - r.metrics.get("n_faded", np.nan) for r in runs]
    found.model_bytes[budget] = [_model_bytes(r) for r in runs]
    found.trainers |= {r.tags["trainer_fingerprint"] for r in runs if r.tags.get("trainer_fingerprint")}
    if len(found.scores[budget]) == 0:
        raise InputError(what, f"no run finished (their errors: MLflow experiment ftgspp/budget_{found.scene})")
