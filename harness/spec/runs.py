"""Which runs an invocation asks for: ``Selection`` (profile, seeds, scenes, variants,
overrides), ``expand`` into ``RunSpec``s (one per seed x scene x variant; run ``r`` uses seed
``base_seed + r``), the ``study run`` command line that reproduces an invocation, and the
standalone commands (``ftgspp synth`` + ``ftgspp train``) that reproduce one run by hand.
"""

from __future__ import annotations

import json
import os
import shlex
from dataclasses import dataclass, field

from ftgspp.errors import InputError
from harness.spec.instances import compact_ranges
from harness.spec.known_scene import PRESET as KNOWN_SIZE
from harness.spec.sphere_scene import PRESET as SPHERES
from harness.spec.study_files import require
from harness.spec.study_schema import StudyScene, StudySpec, plural


@dataclass(frozen=True)
class RunSpec:
    """One training run of a study: (variant, scene, seed) with its full override list."""

    study: str
    profile: str
    variant: str
    scene: StudyScene
    seed: int
    overrides: tuple[str, ...]

    @property
    def key(self) -> tuple[str, str, int]:
        return (self.variant, self.scene.name, self.seed)

    @property
    def label(self) -> str:
        return f"{self.variant}/{self.scene.name}/seed{self.seed}"



@dataclass
class Selection:
    """What one invocation asks for on top of the study file."""

    profile: str = "quick"
    seeds: int | None = None  # None: the profile's count
    scenes: list[str] = field(default_factory=list)  # empty: all
    variants: list[str] = field(default_factory=list)  # empty: all
    overrides: list[str] = field(default_factory=list)  # appended to every run


def _pick(requested: list[str], available: list[str], what: str) -> list[str]:
    for name in requested:
        require(name in available, f"--{what}s {name}", f"unknown {what} (available: {', '.join(available)})")
    return [a for a in available if not requested or a in requested]


def expand(study: StudySpec, sel: Selection) -> list[RunSpec]:
    """All runs of ``study`` for ``sel``: seed-major, then scene, then variant.

    A scene may name its own seed count and the subset of variants run on it (ladder rungs
    with fewer seeds, a tuning scene with its own sweep); ``--seeds`` sets every scene's.
    ``--scenes`` names scenes as planned: ``studio`` is instance 0, ``studio@2`` instance 2.
    Only the first seed's runs draw the diagnostics' figures (the reports show that seed's);
    every run measures their numbers.
    """
    prof = study.profile(sel.profile)
    for o in sel.overrides:
        require("=" in o, f"override '{o}'", "expected key=value")
        require(not o.lstrip("+~").startswith("seed="), f"override '{o}'",
                 "seeds come from --seeds and the study's base_seed")
    variants = _pick(sel.variants, list(prof.variants), "variant")
    scene_names = _pick(sel.scenes, [s.name for s in prof.scenes], "scene")
    scenes = [s for s in prof.scenes if s.name in scene_names]
    require(sel.seeds is None or sel.seeds >= 1, "--seeds", "must be at least 1")

    def seeds_of(scene: StudyScene) -> int:
        return sel.seeds if sel.seeds is not None else scene.seeds or prof.seeds

    runs = []
    for r in range(max(seeds_of(s) for s in scenes)):
        seed = study.base_seed + r
        for scene in scenes:
            if r >= seeds_of(scene):
                continue
            for variant in variants:
                if scene.variants and variant not in scene.variants:
                    continue
                overrides = (
                    *prof.overrides,
                    *scene.data_overrides(),
                    *prof.variants[variant],
                    *([] if r == 0 else ["diagnostics_figures=false"]),
                    *sel.overrides,
                    f"seed={seed}",
                )
                runs.append(RunSpec(study.name, prof.name, variant, scene, seed, overrides))
    require(bool(runs), f"--scenes {','.join(scene_names)} --variants {','.join(variants)}",
             "no run of the study has this scene and variant (a scene may run only some variants: study list)")
    return runs


def describe_runs(runs: list[RunSpec]) -> str:
    """``"12 runs = 2 variants x 3 scenes x 2 seeds"``, or ``"... up to ..."`` when scenes
    carry their own seed counts or variant subsets and the runs are not the full product."""
    if not runs:
        return "0 runs"
    n_var, n_scene, n_seed = (len(set(x)) for x in zip(*(r.key for r in runs)))
    full = n_var * n_scene * n_seed == len(runs)
    sizes = f"{plural(n_var, 'variant')} x {plural(n_scene, 'scene')}"
    return (f"{plural(len(runs), 'run')} = {sizes} x {plural(n_seed, 'seed')}" if full else
            f"{plural(len(runs), 'run')} over {sizes}, up to {plural(n_seed, 'seed')} (per-scene seeds and variants)")


def command_line(study: str, sel: Selection, jobs: int = 1, launcher: str = "basic") -> str:
    """The ``study run`` command that reproduces an invocation (a study named by its file's path
    in this process, ``study run path/to/mine.yaml``, by that path)."""
    parts = ["study", "run", study_ref(study), "--profile", sel.profile]
    if launcher != "basic":
        parts += ["--launcher", launcher]
    if sel.seeds is not None:
        parts += ["--seeds", str(sel.seeds)]
    if sel.scenes:
        parts += ["--scenes", ",".join(compact_ranges(list(sel.scenes)))]
    if sel.variants:
        parts += ["--variants", ",".join(sel.variants)]
    if jobs > 1:
        parts += ["--jobs", str(jobs)]
    where = study_method_path(study, sel)
    return (f"PYTHONPATH={shlex.quote(where)} " if where else "") + " ".join(shlex.quote(p) for p in [*parts, *sel.overrides])


def study_ref(study: str) -> str:
    """How commands name a study: by its file's path when this process was given one
    (``study run path/to/mine.yaml``), else by its name."""
    from harness.spec import study_files

    named = study_files.NAMED_FILE
    return str(named) if named is not None and named.stem == study else study


def study_method_path(study: str, sel: Selection) -> str:
    """What ``PYTHONPATH`` the study's methods outside the package need (``method_path`` of every
    variant of the selected profile, joined; "" for studies of built-in methods only, or a study
    this process cannot load)."""
    from harness.spec import study_files

    try:
        prof = study_files.load_study(study).profile(sel.profile)
    except (InputError, OSError, KeyError):
        return ""
    variants = [v for name, v in prof.variants.items() if not sel.variants or name in sel.variants]
    return os.pathsep.join(sorted({method_path([*v, *sel.overrides]) for v in variants} - {""}))


# generator arguments with a flag of their own in ``ftgspp synth``; the others go through --set
SYNTH_FLAGS = {"layout": "--layout", "preset": "--preset", "seed": "--seed", "n_cameras": "--cameras",
               "n_frames": "--frames", "width": "--width", "height": "--height", "color_shift": "--color-shift",
               "noise": "--noise", "speed": "--speed", "codec": "--codec"}


# the harness's own scene presets and the modules that write them (``python -m MODULE --out ...``)
HARNESS_WRITERS = {KNOWN_SIZE: "harness.run.known_size", SPHERES: "harness.run.spheres"}


def standalone_command(run: RunSpec, threads: str = "") -> str:
    """Shell commands that reproduce ``run`` without the harness: generate its synthetic scene
    (if it has one) and train it with every override the study added. ``threads``: the torch
    thread count the run used, pinned when the config leaves it to the process (a run's bits
    depend on it in the default determinism mode)."""
    parts = []
    scene = run.scene
    writer = HARNESS_WRITERS.get(scene.synth.get("preset")) if scene.synth is not None else None
    if writer:  # the harness's own scenes have their own writers
        synth = ["python", "-m", writer, "--out", scene.synth_dir, "--seed", str(scene.synth["seed"])]
        synth += [f"--set={key}={json.dumps(value)}" for key, value in scene.synth.items()
                  if key not in ("preset", "seed", "layout")]
        parts.append(" ".join(shlex.quote(p) for p in synth))
    elif scene.synth is not None:
        synth = ["ftgspp", "synth", "--out", scene.synth_dir]
        for key, value in scene.synth.items():
            flag = SYNTH_FLAGS.get(key)
            synth += [flag, str(value)] if flag else ["--set", f"{key}={json.dumps(value)}"]
        parts.append(" ".join(shlex.quote(p) for p in synth))
    train = ["ftgspp", "train", *run.overrides]
    if threads and not any(o.startswith("threads=") for o in run.overrides):
        train.append(f"threads={threads}")
    train.append(f"hydra.run.dir=outputs/reproduce/{run.study}/{run.label}")
    where = method_path(run.overrides)
    parts.append((f"PYTHONPATH={shlex.quote(where)} " if where else "") + " ".join(shlex.quote(p) for p in train))
    return " && ".join(parts)


def method_path(overrides: tuple[str, ...] | list[str]) -> str:
    """The folder a run's ``model.method=module:Class`` needs on ``PYTHONPATH`` ("" for the
    built-in methods): the folder holding the module's top package, found without importing it
    (``.`` when that is the clone's root, from which the commands run), else this process's
    ``PYTHONPATH``, else a placeholder that says what to put there."""
    import importlib.util
    import os
    from pathlib import Path

    method = next((o.split("=", 1)[1] for o in overrides if o.startswith("model.method=")), "")
    if ":" not in method:
        return ""
    top = method.split(":", 1)[0].split(".")[0]
    if top == "ftgspp":
        return ""
    try:
        spec = importlib.util.find_spec(top)
    except (ImportError, ValueError):
        spec = None
    if spec is not None and (spec.submodule_search_locations or spec.origin):
        place = Path(list(spec.submodule_search_locations or [])[0] if spec.submodule_search_locations
                     else str(spec.origin)).resolve().parent
        repo = Path(__file__).resolve().parents[2]
        return "." if place == repo else str(place)
    return os.environ.get("PYTHONPATH", "") or f"<the folder that holds {top}>"
