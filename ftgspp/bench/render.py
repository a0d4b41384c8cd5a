"""``ftgspp bench render``: every rasterization backend and the yardstick, timed in one process.

One random scene is projected once (``random_scene.py``); every usable backend (``timing.py``)
rasterizes it, forward and forward + backward, alternating within each repeat; figures are
medians after warm-up. The dense yardstick (``yardstick.py``), the other stages of a ``cpu``
render (``stages.py``) and the Numba compile time (``compile_probe.py``) are measured too.
Compare ratios measured in one run: wall-clock figures depend on the machine and its load.
"""

from __future__ import annotations

import os
import statistics
from typing import Any

import torch

from ftgspp.bench.compile_probe import COMPILE_KEYS, numba_compile_seconds
from ftgspp.bench.isa import describe, host_isa
from ftgspp.bench.random_scene import project_scene, random_scene
from ftgspp.bench.stages import time_stages
from ftgspp.bench.timing import rasterizers, time_backend, time_yardstick


def bench_render(
    n: int = 5000,
    width: int = 128,
    height: int = 96,
    repeats: int = 10,
    warmup: int = 2,
    yardstick_repeats: int = 1,
    compile_times: bool = True,
    seed: int = 0,
) -> dict[str, Any]:
    """Median forward / forward+backward milliseconds of every backend and the yardstick."""
    load_before = os.getloadavg()[0]
    inputs = project_scene(random_scene(n, width, height, seed))
    g = torch.Generator().manual_seed(seed + 1)
    n_dim = inputs["colors"].shape[1]
    cotangents = (
        torch.randn(height, width, n_dim, generator=g),
        torch.randn(height, width, 1, generator=g),
        torch.randn(height, width, 1, generator=g),
    )
    backends = rasterizers()
    names = list(backends)
    for _ in range(warmup):
        for name in names:
            time_backend(backends[name], inputs, cotangents)
    samples: dict[str, list[tuple[float, float]]] = {name: [] for name in names}
    for r in range(repeats):
        for name in names[r % len(names) :] + names[: r % len(names)]:  # alternate the order
            samples[name].append(time_backend(backends[name], inputs, cotangents))
    result: dict[str, Any] = {"backends": {}}
    for name in names:
        fwd, fwd_bwd = zip(*samples[name])
        result["backends"][name] = {"fwd_ms": statistics.median(fwd), "fwd_bwd_ms": statistics.median(fwd_bwd)}
    if yardstick_repeats > 0:
        dense = [time_yardstick(inputs, cotangents) for _ in range(yardstick_repeats)]
        fwd, fwd_bwd = zip(*dense)
        yard = {"fwd_ms": statistics.median(fwd), "fwd_bwd_ms": statistics.median(fwd_bwd)}
        result["yardstick"] = yard
        result["ratios"] = {
            name: {
                "fwd": yard["fwd_ms"] / t["fwd_ms"],
                "fwd_bwd": yard["fwd_bwd_ms"] / t["fwd_bwd_ms"],
            }
            for name, t in result["backends"].items()
        }  # speed-up over the dense yardstick (x)
    else:
        result["yardstick"], result["ratios"] = None, {}
    result.update(
        n=n,
        n_visible=int((inputs["radii"] > 0).all(-1).sum()),
        width=width,
        height=height,
        repeats=repeats,
        torch_threads=torch.get_num_threads(),
        cpu_count=os.cpu_count(),
        load_average=[load_before, os.getloadavg()[0]],  # 1-minute load before and after (ours included)
        isa=host_isa(),
    )
    if "cpu" in backends:
        from ftgspp.render import cpu

        result["numba_threading_layer"] = cpu.threading_layer()
        result["numba_threads"] = __import__("numba").get_num_threads()
        result["stages"] = time_stages(random_scene(n, width, height, seed), repeats, seed)
    result["numba_compile_s"] = numba_compile_seconds() if compile_times else dict.fromkeys(COMPILE_KEYS)
    return result


def pixel_loop_line(pass_name: str, c: dict | None) -> str:
    """One line of ``asm_census.pixel_loop``'s census of a pass's RGB pixel loop."""
    if c is None:
        return f"{pass_name} pixel loop: not found in the assembly"
    return (f"{pass_name} pixel loop, one pass = {c['pixels']} pixels ({c['lanes']}-lane vectors): {c['alu']} vector "
            f"ALU instructions ({c['alu'] / c['pixels']:.2f} a pixel; {c['alu_zmm']} on zmm), {c['load']} loads, "
            f"{c['store']} stores, {c['move']} register moves, {c['mask']} mask, {c['scalar']} scalar; "
            f"{c['instructions']} in all")


def format_render_table(result: dict[str, Any]) -> str:
    """Human-readable table of a ``bench_render`` result."""
    lines = [
        f"render: {result['n']} Gaussians ({result['n_visible']} visible), "
        f"{result['width']}x{result['height']}, median of {result['repeats']}",
        *([describe(result["isa"])] if "isa" in result else []),
        f"{'backend':<11}{'fwd_ms':>12}{'fwd_bwd_ms':>13}{'x yardstick fwd':>17}{'x yardstick fwd+bwd':>21}",
    ]
    rows = dict(result["backends"])
    if result.get("yardstick"):
        rows["yardstick"] = result["yardstick"]
    for name, t in rows.items():
        ratio = result["ratios"].get(name, {"fwd": 1.0, "fwd_bwd": 1.0} if name == "yardstick" else None)
        rf = f"{ratio['fwd']:.1f}" if ratio else "-"
        rb = f"{ratio['fwd_bwd']:.1f}" if ratio else "-"
        lines.append(f"{name:<11}{t['fwd_ms']:>12.2f}{t['fwd_bwd_ms']:>13.2f}{rf:>17}{rb:>21}")
    stages = result.get("stages", {})
    if "prepare" in stages:
        t = stages["prepare"]
        lines.append(f"time eval + SH + projection, fwd+bwd: autograd {t['autograd_ms']:.2f} ms, "
                     f"fused cpu {t['fused_ms']:.2f} ms ({t['autograd_ms'] / t['fused_ms']:.1f}x)")
    if "ssim_loss" in stages:
        t = stages["ssim_loss"]
        lines.append(f"SSIM loss, fwd+bwd: conv2d {t['conv2d_ms']:.2f} ms, numba {t['numba_ms']:.2f} ms "
                     f"({t['conv2d_ms'] / t['numba_ms']:.1f}x)")
    compile_s = result["numba_compile_s"]
    if compile_s.get("cold") is not None and compile_s.get("cached") is not None:
        lines.append(f"numba compile: cold {compile_s['cold']:.1f} s, cached {compile_s['cached']:.2f} s")
    if compile_s.get("cold_raster_ms") is not None and compile_s.get("cached_raster_ms") is not None:
        cold, cached = compile_s["cold_raster_ms"], compile_s["cached_raster_ms"]
        lines.append(f"cpu fwd+bwd at 5k/128x96 in the process that compiled the kernels {cold:.2f} ms, "
                     f"in one that loaded them {cached:.2f} ms ({cold / cached:.2f}x)")
    if "registers" in result:
        r = result["registers"]
        lines.append(f"raster kernels' vector registers: zmm {r['zmm']}, ymm {r['ymm']}, xmm {r['xmm']}; "
                     f"AVX masked moves (vmaskmov) {r.get('vmaskmov', '-')}")
        for key, c in (r.get("pixel_loops") or {}).items():
            lines.append(pixel_loop_line(key, c))
    if "numba_threading_layer" in result:
        lines.append(f"numba: {result['numba_threads']} threads, layer {result['numba_threading_layer']}")
    if result["load_average"][0] > 0.5 * (result["cpu_count"] or 1):
        lines.append(
            f"warning: the machine was busy before the run (1-min load {result['load_average'][0]:.1f} on "
            f"{result['cpu_count']} cores); timings, multi-threaded ones most, are inflated"
        )
    return "\n".join(lines)
