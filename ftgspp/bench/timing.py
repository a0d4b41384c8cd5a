"""Which rasterization backends run here, and one timed call of each (or of the yardstick).

``rasterizers()`` gives the contract ``rasterize`` of every usable backend (``reference``,
``cpu``, and ``gsplat`` on CUDA through ``ftgspp.render.gsplat_adapter``); ``time_backend``
times one forward and one forward + backward for fixed cotangents, ``time_yardstick`` the
same for ``yardstick.dense_rasterize``.
"""

from __future__ import annotations

import time
from typing import Any

import torch
from torch import Tensor

from ftgspp.bench.yardstick import dense_rasterize
from ftgspp.render.contract import Rasterize

GRAD_INPUTS = ("means2d", "conics", "colors", "opacities", "depths", "background")


def usable_backends() -> list[str]:
    """Backends that run on this machine: reference, cpu (Numba importable), gsplat (CUDA + gsplat)."""
    from ftgspp.render import resolve_backend

    names = ["reference"]
    if resolve_backend("auto", torch.device("cpu")) == "cpu":
        names.append("cpu")
    if torch.cuda.is_available() and resolve_backend("auto", torch.device("cuda")) == "gsplat":
        names.append("gsplat")
    return names


def rasterizers() -> dict[str, Rasterize]:
    """Rasterize functions of the backends usable here (contract signature)."""
    backends: dict[str, Rasterize] = {}
    for name in usable_backends():
        if name == "reference":
            from ftgspp.render.reference import rasterize as reference

            backends[name] = reference
        elif name == "cpu":
            from ftgspp.render.cpu import rasterize as cpu

            backends[name] = cpu
        else:
            from ftgspp.render import gsplat_adapter

            backends[name] = _on_cuda(gsplat_adapter.rasterize)
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
