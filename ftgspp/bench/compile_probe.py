"""Numba compile time of the ``cpu`` kernels, measured in fresh processes.

Two subprocesses share an empty ``NUMBA_CACHE_DIR``: the first compiles the kernels (cold),
the second loads them (cached). Each also times the rasterizer, since a process that
compiled the kernels must run them as fast as one that loaded them.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile

_COMPILE_SNIPPET = """
import time, torch
from ftgspp.bench.random_scene import project_scene, random_scene
from ftgspp.bench.stages import stage_model
from ftgspp.bench.timing import time_backend
from ftgspp.image_metrics import ssim_same
from ftgspp.render import cpu
from ftgspp.methods.freetime_fused import prepare
from ftgspp.render.contract import CameraTensors
m = torch.tensor([[8.0, 8.0], [20.0, 9.0]], requires_grad=True)
args = (m, torch.tensor([[0.1, 0.0, 0.1]] * 2), torch.rand(2, 3), torch.rand(2), torch.ones(2))
scene = random_scene(4, 32, 24)
model = stage_model(scene, 0)
t0 = time.perf_counter()
out = cpu.rasterize(*args, torch.tensor([6, 6]), 32, 24)
sum(o.sum() for o in out).backward()
p = prepare(model.params, 0.5, CameraTensors(scene["viewmat"], scene["K"], torch.zeros(3), 32, 24), 3, 1.0, True, 20.0)
(p.means2d.sum() + p.colors.sum()).backward()
(1 - ssim_same(torch.rand(16, 16, 3, requires_grad=True), torch.rand(16, 16, 3))).backward()
first_call = time.perf_counter() - t0
inputs = project_scene(random_scene(5000, 128, 96))
cot = tuple(torch.randn(96, 128, k) for k in (3, 1, 1))
raster_ms = sorted([time_backend(cpu.rasterize, inputs, cot)[1] for _ in range(20)][5:])[7]  # 5 warm-up calls
print(first_call, raster_ms)
"""


COMPILE_KEYS = ("cold", "cached", "cold_raster_ms", "cached_raster_ms")


def numba_compile_seconds() -> dict[str, float | None]:
    """First-call time of the cpu kernels (rasterizer, fused prepare node, SSIM loss): cold
    (empty Numba cache) and cached, in seconds; and the rasterizer's forward + backward at
    5k / 128x96 (median ms) in each of the two processes, ``cold_raster_ms`` and
    ``cached_raster_ms``: a process that compiled the kernels must run them as fast as one
    that loaded them (it once ran them 5-6x slower; see ``cpu_kernels._TILE_JIT``)."""
    result: dict[str, float | None] = dict.fromkeys(COMPILE_KEYS)
    with tempfile.TemporaryDirectory(prefix="ftgspp-numba-") as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        for key in ("cold", "cached"):
            proc = subprocess.run([sys.executable, "-c", _COMPILE_SNIPPET], env=env, capture_output=True, text=True)
            if proc.returncode != 0:
                print(f"warning: compile-time probe failed: {proc.stderr.strip()[-300:]}", file=sys.stderr)
                break
            first_call, raster_ms = proc.stdout.strip().splitlines()[-1].split()
            result[key], result[f"{key}_raster_ms"] = float(first_call), float(raster_ms)
    return result
