"""``ftgspp check-gpu --dry-run`` (``scripts/gpu_check.sh --dry-run``): the GPU check without a GPU,
up to its first CUDA call.

What a real run does before it needs the GPU is done here for real, on the CPU, in the
environment the script made (the kit installed into ``--kit-site``, first on ``PYTHONPATH``):

1. the environment, as a real run prints it;
2. a tiny scene through ``ftgspp synth``, then the quick and paper runs' Hydra app
   (``ftgspp train --cfg job``) from the kit, and a smoke-profile training of each method in
   this process with evaluation (the kit's LPIPS-Alex weights) and diagnostics, so their lazy
   imports happen;
3. gsplat's CUDA extension: the torch stand-ins of ``tests/render/gsplat_standins.py`` take its
   place (nothing is compiled) and record every call;
4. the parity suite (``harness.run.gpu_parity``) on CPU tensors: its first gsplat op is the first
   CUDA call of a real run, answered here by a stand-in;
5. where every package this process imported comes from: the kit, or the device's own packages
   (``gpu_kit.DEVICE_HAS``); anything else is a package the device lacks: FAIL;
6. the plan: every training config of a real run composes, every bench command parses.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import platform
import sys
from pathlib import Path
from typing import Any

import torch

from harness.cli.gpu_plan import MODELS, Check, _cmd, bench_commands, paper_overrides, quick_overrides, tail
from harness.cli.gpu_kit import DEVICE_HAS, normalize

# Installed here and imported when present, absent on the device without harm.
OPTIONAL = {
    "cffi": "numba's optional cffi support", "pycparser": "cffi's parser",
    "hydra-joblib-launcher": "a Hydra launcher plugin (Hydra imports every installed one; train uses none)",
    "hydra-submitit-launcher": "a Hydra launcher plugin (Hydra imports every installed one; train uses none)",
}  # fmt: skip
PROJECT = {"ftgspp"}
TINY = ["--width", "64", "--height", "48", "--cameras", "4", "--frames", "6"]


def install_standins() -> list[str]:
    """Put the torch stand-ins in place of gsplat's CUDA extension and nerfacc; returns the list
    every stand-in op appends its name to when called."""
    import pytest

    from tests.render import gsplat_standins

    calls: list[str] = []
    gsplat_standins.install(pytest.MonkeyPatch())
    ops = sys.modules["gsplat.cuda._backend"]._C
    for op in gsplat_standins._OPS:
        def recorded(*args: Any, _op=op, **kwargs: Any) -> Any:
            calls.append(_op.__name__)
            return _op(*args, **kwargs)

        setattr(ops, op.__name__, recorded)
    return calls


def import_origins(kit: set[str], kit_site: Path | None) -> tuple[list[str], list[str]]:
    """(one line per installed distribution this process imported and where it came from; the
    problems). ``kit``: the kit's distributions; ``kit_site``: where the script installed those
    this Python can load (all of them on the device; the pure-Python ones under another Python)."""
    dists = importlib.metadata.packages_distributions()
    installed = set()
    if kit_site is not None:
        installed = {normalize(d.metadata["Name"]) for d in importlib.metadata.distributions(path=[str(kit_site)])}
    origins: dict[str, set[str]] = {}
    for module in list(sys.modules.values()):
        file = getattr(module, "__file__", None)
        if not file:
            continue
        path = Path(file).resolve()
        in_kit = kit_site is not None and path.is_relative_to(kit_site.resolve())
        roots = [i for i, part in enumerate(path.parts) if part in ("site-packages", "dist-packages")]
        if not (in_kit or roots):
            continue  # the project's own modules, the standard library
        # the folder or file right under site-packages names the package (scipy/sparse/_x.so -> scipy)
        first = path.relative_to(kit_site.resolve()).parts[0] if in_kit else path.parts[roots[-1] + 1]
        top = first.split(".")[0]
        if top.startswith("__editable__"):  # the finder of an editable install (this project)
            continue
        for dist in dists.get(top, [top]):
            origins.setdefault(normalize(dist), set()).add("kit" if in_kit else "local")
    lines, problems = [], []
    for dist, where in sorted(origins.items()):
        if dist in PROJECT:
            continue
        if dist in kit:
            state = "kit" if where == {"kit"} else "NOT from the kit" if dist in installed else \
                "local (the kit's wheel is for another Python: not installed here)"  # fmt: skip
            if state == "NOT from the kit":
                problems.append(f"{dist}: the kit installed it, yet it was imported from elsewhere")
        elif dist in DEVICE_HAS:
            state = "device"
        elif dist in OPTIONAL:
            state = f"optional, absent on the device: {OPTIONAL[dist]}"
        else:
            state = "MISSING on the device and not in the kit"
            problems.append(f"{dist}: imported by the check, neither on the device nor in the kit")
        lines.append(f"{dist}: {state}")
    return lines, problems


def dry_run(chk: Check, args: argparse.Namespace) -> None:
    """The steps of the module docstring, recorded on ``chk``."""
    import json

    import gsplat

    manifest = json.loads((args.kit / "kit.json").read_text()) if args.kit else {"wheels": {}}
    kit = {w["name"] for w in manifest["wheels"].values()}
    chk.record("environment", f"dry run: python {platform.python_version()}, torch {torch.__version__}, "
               f"CUDA available: {torch.cuda.is_available()}, gsplat {gsplat.__version__} from "
               f"{Path(gsplat.__file__).parent.parent}", None)  # fmt: skip

    chk.step("dry run 1/5 a tiny scene, the Hydra app, a smoke training of each method")
    scene = chk.work / "tiny"
    rc, text = chk.run(_cmd(["synth", "--out", str(scene), "--preset", "studio", "--seed", "0", *TINY]), "synth.log", 120)
    chk.record("synth", f"ftgspp synth: {'PASS' if rc == 0 else 'FAIL: ' + tail(text)}", rc == 0)
    for name, overrides in (("quick", quick_overrides(scene, "stg", "gsplat", 0)), ("paper", paper_overrides(scene))):
        rc, text = chk.run(_cmd(["train", "--cfg", "job", *overrides]), f"cfg_{name}.log", 120)
        ok = rc == 0 and "backend: gsplat" in text
        chk.record(f"hydra {name}", f"ftgspp train --cfg job ({name} run's overrides): "
                   f"{'PASS' if ok else 'FAIL: ' + tail(text)}", ok)  # fmt: skip
    from harness.run.gpu_speed import timed_training

    for model in MODELS:
        # the reference backend: no Numba raster kernels to compile (a minute and more in a fresh clone)
        overrides = ["profile=smoke", f"model={model}", f"data.path={scene}", "backend=reference", "device=cpu",
                     "eval_lpips=[alex]"]  # fmt: skip
        r = timed_training(overrides, chk.work / "runs" / f"smoke_{model}", 300)
        ok = r["status"] == "FINISHED"
        chk.record(f"smoke {model}", f"smoke training {model} (reference backend, evaluation, diagnostics): "
                   f"{'PASS' if ok else 'FAIL'}: {r['iterations_done']} iterations, status {r['status']}", ok, r)  # fmt: skip

    chk.step("dry run 2/5 gsplat's CUDA extension: the torch stand-ins, nothing compiled")
    calls = install_standins()
    from gsplat.cuda import _backend

    stood_in = _backend.__name__ == "gsplat.cuda._backend" and hasattr(_backend._C, "projection_ewa_3dgs_fused_fwd")
    chk.record("compile", f"gsplat CUDA extension: {'stand-ins in place (dry run)' if stood_in else 'FAIL'}", stood_in)

    chk.step("dry run 3/5 the parity suite on CPU tensors (the first CUDA call)")
    from harness.run.gpu_parity import describe, suite

    results = suite("cpu")
    for name, line in zip(results, describe(results).splitlines()):
        chk.record(f"parity {name}", f"{line} [stand-ins]", bool(results[name].get("passed")), results[name])
    first = calls[0] if calls else None
    chk.record("first cuda call", f"first CUDA call reached: gsplat _C.{first}, answered by the torch stand-in; "
               f"{len(calls)} calls in all" if first else "first CUDA call: FAIL: no gsplat op was called", bool(first),
               {"first": first, "calls": len(calls), "ops": sorted(set(calls))})  # fmt: skip

    chk.step("dry run 4/5 where every imported package comes from")
    lines, problems = import_origins(kit, args.kit_site)
    for ln in lines:
        print(f"    {ln}", flush=True)
    chk.record("imports", f"imports: {'PASS' if not problems else 'FAIL'}: {len(lines)} distributions, "
               f"{sum('kit' == ln.split(': ', 1)[1] for ln in lines)} from the kit"
               + (f"; {'; '.join(problems)}" if problems else ""), not problems, lines)  # fmt: skip

    chk.step("dry run 5/5 the plan of the GPU steps")
    chk.record("plan", plan_check(scene, args.seed), None)


def plan_check(scene: Path, seed: int) -> str:
    """Compose every training config of a real run and parse every bench command; raises on the
    first that does not, else one line naming them."""
    from ftgspp.bench.cli import build_parser as bench_parser
    from harness.run.gpu_speed import build_parser as speed_parser
    from harness.spec.schema import compose, to_train_config

    configs = [quick_overrides(scene, m, b, seed) for m in MODELS for b in ("gsplat", "cpu")]
    for overrides in [*configs, paper_overrides(scene)]:
        to_train_config(compose(overrides))
    benches = bench_commands()
    for key, argv in benches.items():
        (speed_parser().parse_args(argv) if key == "bench render 500k" else bench_parser().parse_args(argv[1:]))
    return (f"plan: {len(configs) + 1} training configs compose, {len(benches)} bench commands parse; "
            f"not run (dry run): quick runs on gsplat and cpu, {', '.join(benches)}, paper profile")
