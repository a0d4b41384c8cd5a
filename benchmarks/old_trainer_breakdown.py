"""Per-phase breakdown of the trainer before the 2026-11-22 rewrite (commit c956dfe), with
this repository's ``PhaseTimer`` wrapped around the old code's seams (BENCHMARKS.md).

    mkdir /tmp/old && git archive c956dfe | tar -x -C /tmp/old
    PYTHONPATH=/tmp/old .venv/bin/python benchmarks/old_trainer_breakdown.py 200
"""
import importlib.util
import json
import os
import sys
import tempfile
from pathlib import Path

_here = Path(__file__).resolve().parents[1] / "ftgspp" / "bench_phases.py"
spec = importlib.util.spec_from_file_location("bench_phases_now", _here)
bp = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bp)
import ftgspp  # noqa: E402  (the old tree, from PYTHONPATH)

assert os.environ.get("PYTHONPATH", "") and Path(ftgspp.__file__).resolve().parents[1] != _here.parents[1], \
    "put the old tree first on PYTHONPATH"
from ftgspp.config import DataConfig, TrainConfig
from ftgspp.data.load import load_scene
from ftgspp.data.synthetic import generate
from ftgspp.trainer import train
OLD_SEAMS = (
    ("data (frame lookup)", "ftgspp.data.scene:Scene.image"),
    ("model at time t", "ftgspp.model:FreeTimeGaussians.at_time"),
    ("SH colour", "ftgspp.view:eval_sh"),
    ("projection", "ftgspp.render.project:project"),
    ("rasterize forward", "ftgspp.render.cpu:_RasterizeCPU.forward"),
    ("rasterize backward", "ftgspp.render.cpu:_RasterizeCPU.backward"),
    ("loss forward", "ftgspp.trainer:photometric"),
    ("loss forward", "ftgspp.trainer:opacity_4d"),
    ("loss forward", "ftgspp.trainer:scale_penalty"),
    ("backward (rest)", "torch:Tensor.backward"),
    ("optimizer", "torch.optim:Adam.step"),
    ("relocation (amortised)", "ftgspp.strategy.relocate:Relocator.step"),
    ("relocation statistics", "ftgspp.strategy.relocate:Relocator.accumulate"),
    ("checkpoint", "ftgspp.trainer:_save_checkpoint"),
)
iters = int(sys.argv[1]) if len(sys.argv) > 1 else 200
with tempfile.TemporaryDirectory() as tmp:
    root = Path(tmp)
    sd = generate(root / "scene", preset="studio", seed=0, width=128, height=96, n_frames=10, n_cameras=8)
    scene = load_scene(DataConfig(path=str(sd)))
    def cfg(name, it):
        c = TrainConfig(iterations=it, budget=5000, backend="cpu", seed=0, progress=False, diagnostics=False, resume=False, out_dir=str(root / name))
        c.data.path = str(sd); c.init.keyframe_stride = 5; c.strategy.refine_start_iter = 0; c.strategy.refine_stop_iter = it + 1
        c.checkpoint_every = 10**9
        return c
    train(cfg("warm", 3), scene)
    plain = [1000 * train(cfg(f"p{r}", iters), scene).metrics["train_seconds"] / iters for r in range(2)]
    with bp.PhaseTimer(OLD_SEAMS) as t:
        train(cfg("phases", iters), scene)
    print(json.dumps({"ms_per_iter": sorted(plain)[0], "all": plain, "phases": t.per_iteration(iters)}))
