"""``ftgspp bench``: timings of the rasterization backends, measured in one process.

    ftgspp bench render [--n 5000] [--width 128 --height 96] [--repeats 10] [--json]
    python -m ftgspp.bench render --n 20000 --width 256 --height 192

``bench render`` builds one random scene of 3D Gaussians in front of a camera, projects it
once (``ftgspp.render.project``), and times the 2D rasterization of every available backend
(``reference``, ``cpu``, and ``gsplat`` on CUDA) on the same projected Gaussians: forward,
and forward + backward (gradients of all rasterizer inputs for fixed random cotangents).
Backends alternate within each repeat; figures are medians after warm-up. A fixed
yardstick -- dense PyTorch compositing of every Gaussian-pixel pair, chunked over pixels so
memory stays bounded -- is timed too, so that speed-ups stay comparable when the reference
backend changes. Numba compile time of the ``cpu`` kernels is measured cold (a subprocess
with an empty ``NUMBA_CACHE_DIR``) and cached (a second subprocess reusing it).

With the ``cpu`` backend it also times the other stages of a training render, each against
the PyTorch version it replaces: time evaluation + SH colour + projection (the fused Numba
node vs ``at_time`` / ``eval_sh`` / ``project`` under autograd), and the SSIM loss (Numba
kernels vs grouped ``conv2d``), forward + backward.

Wall-clock figures depend on the machine and on what else runs on it; compare ratios
measured in one run. ``bench train`` (``bench_train.py``) times whole training iterations.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from typing import Any

import torch
from torch import Tensor

from ftgspp.render.contract import ALPHA_MAX, ALPHA_MIN, T_MIN, TILE_SIZE

Rasterize = Callable[..., "tuple[Tensor, Tensor, Tensor]"]


# ----------------------------------------------------------------------------- scene


def random_scene(n: int, width: int, height: int, seed: int = 0) -> dict[str, Any]:
    """``n`` random 3D Gaussians filling the view of a pinhole camera at the origin.

    Centres are uniform in screen space (10% margin) at depths 2..10; each axis has a
    screen-space standard deviation log-uniform in [0.5, 3] px; opacities uniform in
    [0.05, 1]; RGB colours uniform. Returns the 3D parameters plus ``viewmat`` and ``K``.
    """
    g = torch.Generator().manual_seed(seed)
    focal = 1.2 * width
    K = torch.tensor([[focal, 0.0, (width - 1) / 2], [0.0, focal, (height - 1) / 2], [0.0, 0.0, 1.0]])
    z = 2.0 + 8.0 * torch.rand(n, generator=g)
    u = (torch.rand(n, generator=g) * 1.2 - 0.1) * width
    v = (torch.rand(n, generator=g) * 1.2 - 0.1) * height
    means = torch.stack([(u - K[0, 2]) * z / focal, (v - K[1, 2]) * z / focal, z], dim=-1)
    sigma_px = torch.exp(math.log(0.5) + math.log(6.0) * torch.rand(n, 3, generator=g))
    return dict(
        means=means,  # [N, 3]
        quats=torch.randn(n, 4, generator=g),  # [N, 4]
        scales=sigma_px * z.unsqueeze(-1) / focal,  # [N, 3]
        opacities=0.05 + 0.95 * torch.rand(n, generator=g),  # [N]
        colors=torch.rand(n, 3, generator=g),  # [N, 3]
        viewmat=torch.eye(4),
        K=K,
        width=width,
        height=height,
    )


def project_scene(scene: dict[str, Any]) -> dict[str, Any]:
    """The rasterizer inputs of ``scene`` (detached): means2d, conics, colors, ..., radii."""
    from ftgspp.render.project import project

    with torch.no_grad():
        means2d, conics, depths, radii, _ = project(
            scene["means"], scene["quats"], scene["scales"], scene["viewmat"], scene["K"],
            scene["width"], scene["height"],
        )  # fmt: skip
    return dict(
        means2d=means2d, conics=conics, colors=scene["colors"], opacities=scene["opacities"],
        depths=depths, radii=radii, width=scene["width"], height=scene["height"],
        background=torch.full((scene["colors"].shape[1],), 0.5),
    )  # fmt: skip


# -------------------------------------------------------------------------- yardstick


def dense_rasterize(
    means2d: Tensor,  # [N, 2]
    conics: Tensor,  # [N, 3]
    colors: Tensor,  # [N, D]
    opacities: Tensor,  # [N]
    depths: Tensor,  # [N]
    radii: Tensor,  # [N]
    width: int,
    height: int,
    background: Tensor | None = None,  # [D]
    grads: tuple[Tensor, Tensor, Tensor] | None = None,  # cotangents of image, alpha, depth
    chunk_pairs: int = 1 << 23,
) -> tuple[Tensor, Tensor, Tensor]:
    """The yardstick: the rasterizer contract evaluated densely on every Gaussian-pixel pair.

    Pixels are processed in chunks of about ``chunk_pairs / N`` pixels. With ``grads``, each
    chunk is differentiated right away (``backward`` of <outputs, cotangents>), so gradients
    accumulate in the leaves' ``.grad`` and memory stays bounded. Returns detached outputs.
    """
    n = colors.shape[0]
    tiles_x, tiles_y = -(-width // TILE_SIZE), -(-height // TILE_SIZE)
    order = torch.sort(depths.detach(), stable=True).indices  # [N] front to back
    with torch.no_grad():
        r = radii.to(means2d.dtype)[order]
        x, y = means2d.detach()[order].unbind(-1)
        tx0 = torch.floor((x - r) / TILE_SIZE).clamp(0, tiles_x)
        tx1 = torch.where(r > 0, torch.floor((x + r + TILE_SIZE - 1) / TILE_SIZE).clamp(0, tiles_x), tx0)
        ty0 = torch.floor((y - r) / TILE_SIZE).clamp(0, tiles_y)
        ty1 = torch.floor((y + r + TILE_SIZE - 1) / TILE_SIZE).clamp(0, tiles_y)
    pix = torch.arange(width * height)
    outs: list[list[Tensor]] = [[], [], []]
    step = max(1, chunk_pairs // max(n, 1))
    for start in range(0, width * height, step):
        p = pix[start : start + step]  # [P]
        px, py = (p % width).to(means2d.dtype), (p // width).to(means2d.dtype)
        with torch.no_grad():
            tx, ty = (px // TILE_SIZE).unsqueeze(-1), (py // TILE_SIZE).unsqueeze(-1)  # [P, 1]
            in_tile = (tx >= tx0) & (tx < tx1) & (ty >= ty0) & (ty < ty1)  # [P, N]
        mean, conic = means2d[order], conics[order]
        dx = px.unsqueeze(-1) - mean[:, 0]  # [P, N]
        dy = py.unsqueeze(-1) - mean[:, 1]
        power = -0.5 * conic[:, 0] * dx * dx + -0.5 * conic[:, 2] * dy * dy - conic[:, 1] * dy * dx
        alpha = torch.clamp(opacities[order] * torch.exp(torch.clamp(power, max=0.0)), max=ALPHA_MAX)
        with torch.no_grad():
            keep = in_tile & (power <= 0) & (alpha >= ALPHA_MIN)
        alpha = torch.where(keep, alpha, 0.0)
        trans = torch.cumprod(1.0 - alpha, dim=-1)  # [P, N] T after each Gaussian
        with torch.no_grad():
            alive = trans >= T_MIN  # a prefix: T never increases
        alpha = torch.where(alive, alpha, 0.0)
        trans = torch.cumprod(1.0 - alpha, dim=-1)
        t_before = torch.cat([torch.ones_like(trans[:, :1]), trans[:, :-1]], dim=-1)
        weights = alpha * t_before  # [P, N]
        t_final = trans[:, -1:]  # [P, 1]
        image = weights @ colors[order]  # [P, D]
        if background is not None:
            image = image + t_final * background
        depth = weights @ depths[order].unsqueeze(-1)  # [P, 1]
        chunk = (image, 1.0 - t_final, depth)
        if grads is not None:
            cot = [g.reshape(width * height, -1)[start : start + step] for g in grads]
            torch.autograd.backward(chunk, cot)
        for acc, t in zip(outs, chunk):
            acc.append(t.detach())
    image, alpha, depth = (torch.cat(o).reshape(height, width, -1) for o in outs)
    return image, alpha, depth


# --------------------------------------------------------------------------- backends


GRAD_INPUTS = ("means2d", "conics", "colors", "opacities", "depths", "background")


def available_backends() -> dict[str, Rasterize]:
    """Rasterize functions of the backends usable here (contract signature)."""
    from ftgspp.render import resolve_backend

    backends: dict[str, Rasterize] = {}
    from ftgspp.render.reference import rasterize as reference

    backends["reference"] = reference
    try:
        from ftgspp.render.cpu import rasterize as cpu

        backends["cpu"] = cpu
    except ImportError:
        pass
    if torch.cuda.is_available() and resolve_backend("auto", torch.device("cuda")) == "gsplat":
        from ftgspp.render import gsplat_adapter

        backends["gsplat"] = _on_cuda(gsplat_adapter.rasterize)
    return backends


def _on_cuda(rasterize: Rasterize) -> Rasterize:
    """``rasterize`` with its tensor arguments copied to CUDA first (the bench's scene is on the
    CPU; the copies are timed with the call, and gradients flow back to the CPU leaves)."""

    def on_cuda(*args: Any) -> tuple[Tensor, Tensor, Tensor]:
        return rasterize(*(a.to("cuda") if isinstance(a, Tensor) else a for a in args))

    return on_cuda


def _sync() -> None:
    if torch.cuda.is_available():
        torch.cuda.synchronize()


def time_backend(fn: Rasterize, inputs: dict[str, Any], cotangents: tuple[Tensor, ...]) -> tuple[float, float]:
    """One forward and one forward + backward of ``fn``, in milliseconds."""
    leaves = {k: inputs[k].clone().requires_grad_(True) for k in GRAD_INPUTS}
    args = [leaves[k] for k in GRAD_INPUTS[:5]]
    extra = (inputs["radii"], inputs["width"], inputs["height"], leaves["background"])
    _sync()
    t0 = time.perf_counter()
    fn(*args, *extra)
    _sync()
    t1 = time.perf_counter()
    outputs = fn(*args, *extra)
    torch.autograd.backward(outputs, [c.to(outputs[0].device) for c in cotangents])
    _sync()
    t2 = time.perf_counter()
    return 1e3 * (t1 - t0), 1e3 * (t2 - t1)


def time_yardstick(inputs: dict[str, Any], cotangents: tuple[Tensor, ...]) -> tuple[float, float]:
    """Dense compositing with autograd: forward and forward + backward, in milliseconds."""
    leaves = {k: inputs[k].clone().requires_grad_(True) for k in GRAD_INPUTS}
    args = [leaves[k] for k in GRAD_INPUTS[:5]] + [inputs["radii"], inputs["width"], inputs["height"]]
    t0 = time.perf_counter()
    dense_rasterize(*args, leaves["background"])  # records each chunk's graph, then drops it
    t1 = time.perf_counter()
    dense_rasterize(*args, leaves["background"], grads=cotangents)
    t2 = time.perf_counter()
    return 1e3 * (t1 - t0), 1e3 * (t2 - t1)


# ----------------------------------------------------------------------- compile time

_COMPILE_SNIPPET = """
import time, torch
from ftgspp.bench import _stage_model, project_scene, random_scene, time_backend
from ftgspp.metrics import ssim_same
from ftgspp.render import cpu
from ftgspp.render.prepare import prepare
m = torch.tensor([[8.0, 8.0], [20.0, 9.0]], requires_grad=True)
args = (m, torch.tensor([[0.1, 0.0, 0.1]] * 2), torch.rand(2, 3), torch.rand(2), torch.ones(2))
scene = random_scene(4, 32, 24)
model = _stage_model(scene, 0)
t0 = time.perf_counter()
out = cpu.rasterize(*args, torch.tensor([6, 6]), 32, 24)
sum(o.sum() for o in out).backward()
p = prepare(model.params, 0.5, scene["viewmat"], scene["K"], torch.zeros(3), 32, 24, 3, 1.0, True, 20.0)
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


# ------------------------------------------------------------------------ other stages


def _stage_model(scene: dict[str, Any], seed: int) -> Any:
    """A FreeTimeGS++ model (gate on, max_duration 1 s, SH degree 3) whose Gaussians at t = 0.5
    are ``scene``'s 3D Gaussians (the bench camera sits at the world origin)."""
    from ftgspp.config import ModelConfig
    from ftgspp.model import FreeTimeGaussians

    g = torch.Generator().manual_seed(seed + 2)
    n = scene["means"].shape[0]
    times = torch.rand(n, generator=g)
    velocities = 0.05 * torch.randn(n, 3, generator=g)
    params = {
        "means": scene["means"] - velocities * (0.5 - times)[:, None],
        "velocities": velocities,
        "times": times,
        "durations": torch.randn(n, generator=g),
        "scales": torch.log(scene["scales"]),
        "quats": scene["quats"],
        "opacities": torch.logit(scene["opacities"].clamp(1e-4, 1 - 1e-4)),
        "sh0": ((scene["colors"] - 0.5) / 0.28209479177387814)[:, None, :],
        "shN": 0.05 * torch.randn(n, 15, 3, generator=g),
        "gates": -1.0 + 0.1 * torch.randn(n, generator=g),
    }
    return FreeTimeGaussians(params, ModelConfig(max_duration=1.0, gate=True))


def time_stages(scene: dict[str, Any], repeats: int, seed: int = 0) -> dict[str, dict[str, float]]:
    """Median forward + backward milliseconds of the other stages of a ``cpu`` training render.

    ``prepare``: time evaluation + SH colour (degree 3) + EWA projection, as PyTorch autograd
    (``at_time``, ``eval_sh``, ``project``: the ``reference`` path) and as the fused Numba node.
    ``ssim_loss``: 1 - SSIM of a rendered-size image, grouped ``conv2d`` vs the Numba kernels.
    """
    from ftgspp.metrics import SSIM_WINDOW, _nchw, _ssim_map, ssim_same
    from ftgspp.render.prepare import prepare
    from ftgspp.render.project import project
    from ftgspp.render.sh import eval_sh

    model = _stage_model(scene, seed)
    params, width, height = model.params, scene["width"], scene["height"]
    viewmat, K, centre = scene["viewmat"], scene["K"], torch.zeros(3)
    g = torch.Generator().manual_seed(seed + 3)
    n = len(model)
    cot = [torch.randn(n, k, generator=g) for k in (2, 3, 3)] + [torch.randn(n, generator=g) for _ in range(2)]

    def weighted(outputs: tuple[Tensor, ...]) -> Tensor:
        return sum((o * c).sum() for o, c in zip(outputs, cot))

    def autograd_prepare() -> None:
        at = model.at_time(0.5)
        dirs = at.means - centre
        colors = eval_sh(3, at.sh, dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-8))
        means2d, conics, depths, _, _ = project(at.means, at.quats, at.scales, viewmat, K, width, height)
        weighted((means2d, conics, colors, at.opacities, depths)).backward()

    def fused_prepare() -> None:
        p = prepare(params, 0.5, viewmat, K, centre, width, height, 3, 1.0, True, model.cfg.gate_gamma)
        weighted((p.means2d, p.conics, p.colors, p.opacities, p.depths)).backward()

    pred = torch.rand(height, width, 3, generator=g).requires_grad_(True)
    gt = torch.rand(height, width, 3, generator=g)

    def conv_ssim() -> None:
        ssim = _ssim_map(_nchw(pred[None]), _nchw(gt[None]), 1.0, padding=SSIM_WINDOW // 2).mean()
        (1.0 - ssim).backward()

    def numba_ssim() -> None:
        (1.0 - ssim_same(pred, gt)).backward()

    stages = {"prepare": {"autograd": autograd_prepare, "fused": fused_prepare},
              "ssim_loss": {"conv2d": conv_ssim, "numba": numba_ssim}}  # fmt: skip
    samples: dict[str, dict[str, list[float]]] = {k: {v: [] for v in fns} for k, fns in stages.items()}
    for r in range(repeats + 2):  # the first two are warm-up
        for stage, fns in stages.items():
            for variant, fn in fns.items():
                t0 = time.perf_counter()
                fn()
                if r >= 2:
                    samples[stage][variant].append(1e3 * (time.perf_counter() - t0))
        for p in [*params.values(), pred]:
            p.grad = None
    return {stage: {f"{v}_ms": statistics.median(t) for v, t in variants.items()} for stage, variants in samples.items()}


# ------------------------------------------------------------------------------ render


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
    backends = available_backends()
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
        n_visible=int((inputs["radii"] > 0).sum()),
        width=width,
        height=height,
        repeats=repeats,
        torch_threads=torch.get_num_threads(),
        cpu_count=os.cpu_count(),
        load_average=[load_before, os.getloadavg()[0]],  # 1-minute load before and after (ours included)
    )
    if "cpu" in backends:
        from ftgspp.render import cpu

        result["numba_threading_layer"] = cpu.threading_layer()
        result["numba_threads"] = __import__("numba").get_num_threads()
        result["stages"] = time_stages(random_scene(n, width, height, seed), repeats, seed)
    result["numba_compile_s"] = numba_compile_seconds() if compile_times else dict.fromkeys(COMPILE_KEYS)
    return result


def format_render_table(result: dict[str, Any]) -> str:
    """Human-readable table of a ``bench_render`` result."""
    lines = [
        f"render: {result['n']} Gaussians ({result['n_visible']} visible), "
        f"{result['width']}x{result['height']}, median of {result['repeats']}",
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
    if "numba_threading_layer" in result:
        lines.append(f"numba: {result['numba_threads']} threads, layer {result['numba_threading_layer']}")
    if result["load_average"][0] > 0.5 * (result["cpu_count"] or 1):
        lines.append(
            f"warning: the machine was busy before the run (1-min load {result['load_average'][0]:.1f} on "
            f"{result['cpu_count']} cores); timings, multi-threaded ones most, are inflated"
        )
    return "\n".join(lines)


# -------------------------------------------------------------------------------- cli


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="ftgspp bench", description="Time rasterization and training.")
    sub = parser.add_subparsers(dest="command", required=True)
    render = sub.add_parser("render", help="forward / forward+backward of every rasterization backend")
    render.add_argument("--n", type=int, default=5000, help="number of 3D Gaussians")
    render.add_argument("--width", type=int, default=128)
    render.add_argument("--height", type=int, default=96)
    render.add_argument("--repeats", type=int, default=10, help="timed repeats per backend (median)")
    render.add_argument("--warmup", type=int, default=2)
    render.add_argument("--yardstick-repeats", type=int, default=1, help="0 skips the dense yardstick")
    render.add_argument("--no-compile-times", action="store_true", help="skip the Numba compile probe")
    render.add_argument("--seed", type=int, default=0)
    render.add_argument("--json", action="store_true", help="print one JSON line instead of a table")
    from ftgspp.bench_train import add_parsers

    add_parsers(sub)  # train, scale
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``ftgspp bench``. Returns the exit status."""
    args = build_parser().parse_args(argv)
    if args.command == "render":
        result = bench_render(
            n=args.n, width=args.width, height=args.height, repeats=args.repeats, warmup=args.warmup,
            yardstick_repeats=args.yardstick_repeats, compile_times=not args.no_compile_times, seed=args.seed,
        )  # fmt: skip
        print(json.dumps(result) if args.json else format_render_table(result))
        return 0
    from ftgspp.bench_train import run

    return run(args)


if __name__ == "__main__":
    raise SystemExit(main())
