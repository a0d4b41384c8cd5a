"""Per-phase milliseconds of a training iteration, measured inside the real trainer.

``PhaseTimer`` wraps known seams of the pipeline (functions and autograd nodes) with a
wall-clock timer while the real ``train()`` runs, and charges each call's *exclusive*
time (its own, minus timed calls made inside it) to a phase. Whatever no seam covers
(Python glue, tensor bookkeeping, tqdm) is ``other`` = loop time − Σ phases. Backward
passes are split the same way: autograd calls the backward of each custom node inside
``Tensor.backward``, so ``backward (rest)`` is the backward time no timed node took.

    with PhaseTimer() as timer:
        result = train(cfg, scene)
    timer.per_iteration(cfg.iterations)   # {"rasterize forward": 1.9, ...} in ms

Only time inside the trainer's loop (``trainer._loop``) counts: initialisation,
evaluation and diagnostics call the same functions but are not iterations.

Wall-clock timing is right on the CPU; on CUDA it would need synchronisation (GPU
timings are out of scope here).
"""

from __future__ import annotations

import functools
import importlib
import time
from collections import defaultdict
from typing import Any, Callable

import numpy as np

# (phase, "module:attribute.path"). The first seams that exist are wrapped; a missing one
# (another backend, an older module layout) is skipped, and its time lands in its parent.
SEAMS: tuple[tuple[str, str], ...] = (
    ("data (frame lookup)", "ftgspp.data.scene:Scene.image"),
    ("model at time t", "ftgspp.methods.freetime:FreeTimeGaussians.at_time"),
    ("model at time t", "ftgspp.methods.stg:SpacetimeGaussians.at_time"),
    ("SH colour", "ftgspp.view:eval_sh"),
    ("projection", "ftgspp.render.project:project"),
    ("prepare forward (time + SH + projection)", "ftgspp.render.prepare:_PrepareCPU.forward"),
    ("prepare backward", "ftgspp.render.prepare:_PrepareCPU.backward"),
    ("rasterize forward", "ftgspp.render.cpu:_RasterizeCPU.forward"),
    ("rasterize backward", "ftgspp.render.cpu:_RasterizeCPU.backward"),
    ("rasterize forward", "ftgspp.render.reference:rasterize"),
    ("loss forward", "ftgspp.trainer:loss_terms"),
    ("SSIM backward", "ftgspp.ssim_cpu:_SSIMSame.backward"),
    ("backward (rest)", "torch:Tensor.backward"),
    ("optimizer", "torch.optim:Adam.step"),
    ("optimizer", "ftgspp.trainer:adam_step"),  # the trainer's own binding of ftgspp.optim.adam_step
    ("relocation (amortised)", "ftgspp.strategy.relocate:Relocator.step"),
    ("relocation statistics", "ftgspp.strategy.relocate:Relocator.accumulate"),
    ("checkpoint", "ftgspp.train_state:TrainState.save"),
)
ORDER = [phase for phase, _ in SEAMS] + ["other (Python, glue)"]


def _resolve(target: str) -> tuple[Any, str, Any] | None:
    """``(owner, attribute name, raw attribute)`` of ``"module:Owner.attr"``; None if absent."""
    module_name, path = target.split(":")
    try:
        owner: Any = importlib.import_module(module_name)
    except ImportError:
        return None
    *parents, attr = path.split(".")
    for name in parents:
        owner = getattr(owner, name, None)
        if owner is None:
            return None
    # on a class, take the raw attribute (staticmethod objects stay what they are)
    namespace = vars(owner) if isinstance(owner, type) else None
    if namespace is not None:
        return (owner, attr, namespace[attr]) if attr in namespace else None
    return (owner, attr, getattr(owner, attr)) if hasattr(owner, attr) else None


class PhaseTimer:
    """Context manager: wraps ``SEAMS`` while active; ``totals`` holds exclusive seconds per phase."""

    def __init__(self, seams: tuple[tuple[str, str], ...] = SEAMS) -> None:
        self.seams = seams
        self.totals: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self._stack: list[float] = []  # child time accumulated by each open timed call
        self._undo: list[tuple[Any, str, Any]] = []
        self._in_loop = False
        self.loop_seconds = 0.0  # wall time inside the trainer's loop
        # the cpu rasterizer's work inside the loop (``_count_work``): what its time is spent on
        self.work: dict[str, int] = defaultdict(int)

    def _gate(self, fn: Callable) -> Callable:
        """Wrap the trainer's loop: phases are recorded only while it runs."""

        @functools.wraps(fn)
        def loop(*args, **kwargs):
            self._in_loop = True
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                self.loop_seconds += time.perf_counter() - t0
                self._in_loop = False

        return loop

    def _wrap(self, phase: str, fn: Callable) -> Callable:
        @functools.wraps(fn)
        def timed(*args, **kwargs):
            if not self._in_loop:  # initialisation, evaluation, diagnostics: not an iteration
                return fn(*args, **kwargs)
            self._stack.append(0.0)
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                spent = time.perf_counter() - t0
                children = self._stack.pop()
                self.totals[phase] += spent - children
                self.calls[phase] += 1
                if self._stack:
                    self._stack[-1] += spent

        return timed

    def _count_work(self, fn: Callable) -> Callable:
        """Wrap ``cpu._forward``: per rendered view, its (tile, Gaussian) pairs, the pairs that
        reached some pixel, the Gaussians with a pair, and the slots every pixel walked through its
        tile's depth-sorted list (``stop_slot``: where the pixel stopped, else the list's length):
        the rasterizer's work."""

        @functools.wraps(fn)
        def counted(*args, **kwargs):
            binning, fwd = fn(*args, **kwargs)
            if self._in_loop:
                self.work["views"] += 1
                self.work["Gaussians drawn"] += int(np.count_nonzero(np.diff(binning.gauss_off)))
                self.work["tile pairs"] += int(binning.offsets[-1])
                self.work["live pairs"] += int(fwd.pair_live.sum())
                self.work["pixel slots"] += int(fwd.stop_slot.sum(dtype=np.int64))
                self.work["pixels"] += int(fwd.stop_slot.size)
            return binning, fwd

        return counted

    def __enter__(self) -> "PhaseTimer":
        import ftgspp.trainer as trainer

        self._undo.append((trainer, "_loop", trainer._loop))
        trainer._loop = self._gate(trainer._loop)
        found = _resolve("ftgspp.render.cpu:_forward")
        if found is not None:
            owner, attr, raw = found
            setattr(owner, attr, self._count_work(raw))
            self._undo.append((owner, attr, raw))
        for phase, target in self.seams:
            found = _resolve(target)
            if found is None:
                continue
            owner, attr, raw = found
            if isinstance(raw, staticmethod):
                wrapped: Any = staticmethod(self._wrap(phase, raw.__func__))
            elif isinstance(raw, classmethod):
                wrapped = classmethod(self._wrap(phase, raw.__func__))
            else:
                wrapped = self._wrap(phase, raw)
            setattr(owner, attr, wrapped)
            self._undo.append((owner, attr, raw))
        return self

    def __exit__(self, *exc: object) -> None:
        for owner, attr, raw in reversed(self._undo):
            setattr(owner, attr, raw)
        self._undo.clear()

    def per_iteration(self, iterations: int) -> dict[str, float]:
        """Milliseconds per iteration for every phase, ``other`` included; sums to the loop time."""
        ms = {phase: 1000.0 * self.totals[phase] / iterations for phase in ORDER if phase in self.totals}
        ms["other (Python, glue)"] = 1000.0 * self.loop_seconds / iterations - sum(ms.values())
        return ms

    def work_per_view(self) -> dict[str, float]:
        """The cpu rasterizer's work per rendered view (empty when it never ran in the loop), and
        its forward + backward time per pixel slot walked (ns): equal costs per slot say a time gap
        between two methods is work, not code."""
        views = self.work.get("views", 0)
        if not views:
            return {}
        out = {"Gaussians drawn": self.work["Gaussians drawn"] / views,
               "tile pairs": self.work["tile pairs"] / views, "live pairs": self.work["live pairs"] / views,
               "slots per pixel": self.work["pixel slots"] / self.work["pixels"]}
        raster_s = self.totals.get("rasterize forward", 0.0) + self.totals.get("rasterize backward", 0.0)
        out["rasterize ns per pixel slot"] = 1e9 * raster_s / max(self.work["pixel slots"], 1)
        return out
