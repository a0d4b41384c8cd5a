"""Which vector instructions a benchmark ran with, and running one for another CPU target.

The ``cpu`` backend's Numba kernels are compiled for the host's CPU (LLVM's host name and
features) unless ``NUMBA_CPU_NAME`` / ``NUMBA_CPU_FEATURES`` say otherwise; torch picks its
own kernel set (``torch.backends.cpu.get_cpu_capability``). ``host_isa`` records both with
every benchmark result. ``run_for_target`` re-runs a benchmark in a child process whose Numba
kernels are compiled for a named LLVM CPU (its default features, its own empty cache) and
whose torch kernel dispatch (``ATEN_CPU_CAPABILITY``) and oneDNN are capped at that CPU's
vector ISA, so an AVX-512 host can measure what an AVX2 host gets from the instruction set
(MKL inside torch, glibc's libm, NumPy and OpenCV still choose their own code paths, and the
microarchitecture stays this host's); a target whose instructions this host lacks is refused
(the child would die of an illegal instruction). ``kernel_registers`` counts the
vector registers in the compiled rasterizer kernels' assembly: ``zmm`` are 512-bit, ``ymm``
256-bit, ``xmm`` 128-bit (and scalar floating point), and AVX's masked moves (``vmaskmovps``),
which the pixel loops avoid (slow stores on AMD cores; ``cpu_kernels._pick``).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tempfile
from typing import Any

from ftgspp.errors import InputError

# LLVM CPU names -> the widest vector extension they imply (the ones users will ask for)
TARGET_ISA = {
    "generic": "sse2", "x86-64": "sse2", "x86-64-v2": "sse4.2", "x86-64-v3": "avx2", "x86-64-v4": "avx512f",
    "haswell": "avx2", "broadwell": "avx2", "skylake": "avx2", "alderlake": "avx2",
    "znver1": "avx2", "znver2": "avx2", "znver3": "avx2",
    "skylake-avx512": "avx512f", "cascadelake": "avx512f", "icelake-server": "avx512f",
    "sapphirerapids": "avx512f", "znver4": "avx512f",
}  # fmt: skip
ISA_NAMES = {"avx512f": "AVX-512", "avx2": "AVX2", "sse4.2": "SSE4.2", "sse2": "SSE2"}
# What a host of each ISA gets from torch (``ATEN_CPU_CAPABILITY``) and oneDNN (``ONEDNN_MAX_CPU_ISA``)
TORCH_KERNELS = {"avx512f": "avx512", "avx2": "avx2", "sse4.2": "default", "sse2": "default"}
ONEDNN_ISA = {"avx512f": "AVX512_CORE", "avx2": "AVX2", "sse4.2": "SSE41", "sse2": "SSE41"}
ORDER = ("sse2", "sse4.2", "avx2", "avx512f")


def _host_features() -> dict[str, bool]:
    import llvmlite.binding as ll

    return {k: bool(v) for k, v in ll.get_host_cpu_features().items()}


def widest(features: dict[str, bool]) -> str:
    """The widest vector extension in an LLVM feature map (``avx512f``, ``avx2``, ...)."""
    return next((isa for isa in reversed(ORDER) if features.get(isa)), "sse2")


def host_vector_isa() -> str:
    """This host's widest vector ISA by name (``AVX-512``, ``AVX2``, ...; LLVM's host features)."""
    return ISA_NAMES[widest(_host_features())]


def host_isa() -> dict[str, Any]:
    """The host's LLVM CPU and vector ISA, the CPU target the Numba kernels are compiled for in
    this process, and torch's kernel set."""
    import llvmlite.binding as ll
    import torch

    host = ll.get_host_cpu_name()
    target = os.environ.get("NUMBA_CPU_NAME") or host
    host_vec = widest(_host_features())
    target_vec = TARGET_ISA.get(target, host_vec) if target != host else host_vec
    return {"host_cpu": host, "host_isa": ISA_NAMES[host_vec], "numba_target": target,
            "numba_isa": ISA_NAMES.get(target_vec, target_vec),
            "numba_wide": widened(),
            "torch_kernels": torch.backends.cpu.get_cpu_capability()}


def widened() -> bool:
    """Whether this process's Numba compiles with LLVM's 256-bit preference lifted
    (``ftgspp.runtime.jit.widen_vectors``: Intel AVX-512 targets)."""
    from numba.core import config

    from ftgspp.runtime.jit import PREFER_256

    return bool(config.CPU_FEATURES and config.CPU_FEATURES.split(",")[-1] == PREFER_256)


def describe(isa: dict[str, Any]) -> str:
    """One line for a benchmark table."""
    return (f"host {isa['host_cpu']} ({isa['host_isa']}); Numba kernels for {isa['numba_target']}"
            f" ({isa['numba_isa']}); torch kernels {isa['torch_kernels']}"
            + ("; LLVM's 256-bit vector preference lifted" if isa.get("numba_wide") else ""))


def check_target(target: str) -> None:
    """InputError unless ``target`` is a known LLVM CPU whose vector ISA this host has."""
    if target not in TARGET_ISA:
        raise InputError("--target", f"unknown CPU target '{target}' (choose from host, {', '.join(TARGET_ISA)})")
    need = TARGET_ISA[target]
    have = widest(_host_features())
    if ORDER.index(need) > ORDER.index(have):
        raise InputError("--target", f"'{target}' needs {ISA_NAMES[need]}, which this host ({ISA_NAMES[have]}) "
                                     "lacks: its kernels would stop on an illegal instruction")


# Environment variables that choose a process's CPU code (Numba's target, torch's dispatch,
# oneDNN's cap under its new and old names): what a benchmark of "this host" must not inherit
ISA_CHOICES = ("NUMBA_CPU_", "ATEN_CPU", "ONEDNN_MAX", "DNNL_MAX")


def without_isa_choices(environ: dict[str, str]) -> dict[str, str]:
    """``environ`` minus every variable that chooses CPU code (``ISA_CHOICES``)."""
    return {k: v for k, v in environ.items() if not k.startswith(ISA_CHOICES)}


def target_environment(target: str) -> dict[str, str]:
    """Environment of a process that runs as on a host of LLVM CPU ``target``: Numba compiles
    for it (its default features), torch's kernel dispatch and oneDNN are capped at its vector
    ISA (oneDNN's cap is its nearest ISA level). torch takes ``ATEN_CPU_CAPABILITY`` as given,
    even above what the host has, so check the target first (``check_target``)."""
    need = TARGET_ISA[target]
    return {"NUMBA_CPU_NAME": target, "NUMBA_CPU_FEATURES": "",
            "ATEN_CPU_CAPABILITY": TORCH_KERNELS[need], "ONEDNN_MAX_CPU_ISA": ONEDNN_ISA[need]}


CHILD_FLAG = "FTGSPP_BENCH_CHILD"  # set in the child: it runs the benchmark itself


def run_for_target(argv: list[str], target: str, timeout: float = 3600.0) -> dict[str, Any]:
    """Run ``ftgspp bench <argv> --json`` in a fresh process with its own empty kernel cache
    (so its kernels are compiled there and their assembly can be read), for the LLVM CPU
    ``target`` (``host``: this machine's); its JSON result, with ``target`` set."""
    if target != "host":
        check_target(target)
    with tempfile.TemporaryDirectory(prefix=f"ftgspp-target-{target}-") as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, **{CHILD_FLAG: "1"})
        if target != "host":
            env.update(target_environment(target))
        proc = subprocess.run([sys.executable, "-m", "ftgspp.bench", *argv, "--json"], env=env,
                              capture_output=True, text=True, timeout=timeout)
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        raise RuntimeError(f"the benchmark for target {target} failed (exit {proc.returncode}): {last}")
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    result["target"] = target
    return result


def kernel_registers() -> dict | None:
    """Vector registers named in the assembly of the rasterizer's kernels (``render_forward``,
    ``render_backward``: the per-tile loops are inlined into them), and under ``pixel_loops`` the
    instructions of their RGB pixel loops (``asm_census.pixel_loop``, None where none was found);
    None when this process loaded them from the cache (Numba keeps no assembly of cached code)."""
    from ftgspp.bench.asm_census import pixel_loop
    from ftgspp.bench.random_scene import project_scene, random_scene
    from ftgspp.render import cpu_kernels
    from ftgspp.render.cpu import rasterize

    inputs = project_scene(random_scene(200, 32, 24))  # one forward + backward: the kernels exist
    for key in ("means2d", "conics", "colors", "opacities"):
        inputs[key] = inputs[key].clone().requires_grad_(True)
    image, _, _ = rasterize(**inputs)
    image.sum().backward()
    if any(sum(getattr(cpu_kernels, name).stats.cache_hits.values()) for name in ("render_forward", "render_backward")):
        return None
    counts: dict = {"zmm": 0, "ymm": 0, "xmm": 0, "vmaskmov": 0, "pixel_loops": {}}
    for name, key in (("render_forward", "forward"), ("render_backward", "backward")):
        modules = list(getattr(cpu_kernels, name).inspect_asm().values())  # one per signature
        for asm in modules:
            for reg in ("zmm", "ymm", "xmm"):
                counts[reg] += len(re.findall(rf"%{reg}\d+", asm))
            counts["vmaskmov"] += len(re.findall(r"\bvmaskmovp[sd]\b", asm))
        counts["pixel_loops"][key] = pixel_loop(*modules)
    return counts
