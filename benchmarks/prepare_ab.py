"""Two versions of the fused prepare stage, side by side: cold compile time and speed.

A change to ``ftgspp/render/prepare_kernels.py`` or a method's fused kernel that should keep the
speed (the same arithmetic, compiled another way) is checked here: each version's ``ftgspp``
package is exported from git (``--base``, ``--head``; ``.`` is the working tree) into its own
folder with its own Numba cache, and a child process per version and round compiles it cold
(the first round: seconds to the first forward and the first backward) and times the stage on a
random 5,000-Gaussian scene (``ftgspp.bench.stages``): the median of ``--calls`` forward passes
(no gradient) and of as many backward passes, ``--rounds`` rounds with the versions alternating,
one thread by default so that another process on the machine moves it least.

    .venv/bin/python benchmarks/prepare_ab.py --base 2364d5f~1 --head 2364d5f [--method ftgs] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
from io import BytesIO
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, sys, time
import numpy as np, torch
from ftgspp.bench.random_scene import random_scene
from ftgspp.bench.stages import stage_model
from ftgspp.render.contract import CameraTensors

method, n, calls = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
scene = random_scene(n, 128, 96)
camera = CameraTensors(scene["viewmat"], scene["K"], torch.zeros(3), 128, 96)
if method == "ftgs":
    from ftgspp.methods.freetime_fused import prepare
    params = stage_model(scene, 0).params
    def forward():
        return prepare(params, 0.5, camera, 3, 1.0, True, 20.0)
else:
    from ftgspp.config import InitConfig, ModelConfig
    from ftgspp.methods.stg import SpacetimeGaussians
    from ftgspp.methods.stg_fused import prepare
    rng = np.random.default_rng(0)
    model = SpacetimeGaussians.from_points(scene["means"].detach().numpy(), rng.random((n, 3)), rng.random(n),
                                           np.zeros((n, 3)), np.full(n, 0.05),
                                           ModelConfig(name="stg", method="stg", sh_degree=0), InitConfig())
    params = model.params
    def forward():
        return prepare(params, 0.5, camera)

def backward():
    p = forward()
    t = time.perf_counter()
    (p.means2d.sum() + p.colors.sum() + p.conics.sum()).backward()
    return time.perf_counter() - t

t0 = time.perf_counter()
forward()
t1 = time.perf_counter()
backward()
compile_s = (t1 - t0, time.perf_counter() - t1)
fwd, bwd = [], []
for _ in range(calls):
    t = time.perf_counter()
    with torch.no_grad():
        forward()
    fwd.append(time.perf_counter() - t)
    bwd.append(backward())
import ftgspp, os
print(json.dumps({"package": os.path.dirname(ftgspp.__file__), "first_forward_s": compile_s[0], "first_backward_s": compile_s[1],
                  "forward_ms": 1000 * sorted(fwd)[calls // 2], "backward_ms": 1000 * sorted(bwd)[calls // 2]}))
"""


def export(rev: str, into: Path) -> Path:
    """``rev``'s ``ftgspp`` package (``.``: the working tree's) under ``into``; returns the folder to put on
    PYTHONPATH."""
    if rev == ".":
        return ROOT
    data = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", rev, "ftgspp"], capture_output=True,
                          check=True).stdout
    with tarfile.open(fileobj=BytesIO(data)) as tar:
        tar.extractall(into, filter="data")
    return into


def child(path: Path, cache: Path, method: str, n: int, calls: int, threads: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(path), NUMBA_CACHE_DIR=str(cache), NUMBA_NUM_THREADS=str(threads),
               OMP_NUM_THREADS=str(threads), MKL_NUM_THREADS=str(threads))
    # run from the version's folder: ``python -c`` puts the working directory first on sys.path, so from the
    # repository it would import the working tree's ftgspp whatever PYTHONPATH says
    out = subprocess.run([sys.executable, "-c", CHILD, method, str(n), str(calls)], env=env, capture_output=True,
                         text=True, check=True, cwd=path)
    result = json.loads(out.stdout.strip().splitlines()[-1])
    if Path(result.pop("package")).resolve() != (path / "ftgspp").resolve():
        raise RuntimeError(f"the child imported another ftgspp than {path / 'ftgspp'}")
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--base", required=True, help="git revision of the first version ('.': the working tree)")
    parser.add_argument("--head", default=".", help="git revision of the second version (default: the working tree)")
    parser.add_argument("--method", choices=("ftgs", "stg"), default="ftgs")
    parser.add_argument("--gaussians", type=int, default=5000)
    parser.add_argument("--calls", type=int, default=60, help="timed calls a round (the median is kept)")
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    results: dict[str, list[dict]] = {"base": [], "head": []}
    with tempfile.TemporaryDirectory(prefix="prepare_ab_") as tmp:
        paths = {k: export(rev, Path(tmp) / k) for k, rev in (("base", args.base), ("head", args.head))}
        for r in range(args.rounds):
            for k in ("base", "head") if r % 2 == 0 else ("head", "base"):
                results[k].append(child(paths[k], Path(tmp) / f"cache_{k}", args.method, args.gaussians, args.calls,
                                        args.threads))
    summary = {k: {"rev": getattr(args, k), "cold_first_forward_s": v[0]["first_forward_s"],
                   "cold_first_backward_s": v[0]["first_backward_s"],
                   "forward_ms": statistics.median(x["forward_ms"] for x in v),
                   "backward_ms": statistics.median(x["backward_ms"] for x in v),
                   "rounds": v} for k, v in results.items()}
    if args.json:
        print(json.dumps(summary, indent=1))
        return 0
    b, h = summary["base"], summary["head"]
    print(f"{args.method} fused prepare stage, {args.gaussians} Gaussians, {args.threads} thread(s), median of"
          f" {args.rounds} rounds x {args.calls} calls, versions alternating")
    print(f"{'':24}{'base ' + args.base:>22}{'head ' + args.head:>22}{'head/base':>11}")
    for key, label in (("cold_first_forward_s", "cold compile, forward s"), ("cold_first_backward_s",
                       "cold compile, backward s"), ("forward_ms", "forward ms"), ("backward_ms", "backward ms")):
        print(f"{label:24}{b[key]:22.3f}{h[key]:22.3f}{h[key] / b[key]:10.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
