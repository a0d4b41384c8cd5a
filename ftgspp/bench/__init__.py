"""``ftgspp bench``: timings of rasterization and training, measured in one process.

    ftgspp bench render [--n 5000] [--width 128 --height 96] [--repeats 10] [--json]
    ftgspp bench train [--iterations 200] [--budget 5000] [--repeats 2] [--breakdown] [--json]
    ftgspp bench scale [--counts 1000,5000,20000] [--sizes 128x96,256x192] [--json]
    python -m ftgspp.bench render --n 20000 --width 256 --height 192

``render`` (``render.py``) builds one random scene of 3D Gaussians in front of a camera
(``random_scene.py``), projects it once, and times the 2D rasterization of every available backend
(``reference``, ``cpu``, and ``gsplat`` on CUDA; ``timing.py``) on the same projected
Gaussians, forward and forward + backward, against a fixed dense yardstick
(``yardstick.py``). With the ``cpu`` backend it also times the other stages of a training
render against the PyTorch code they replace (``stages.py``) and the Numba compile time,
cold and cached (``compile_probe.py``).

``train`` (``train_speed.py``) times whole training iterations of every backend through the real
trainer, ``--breakdown`` per phase (``phases.py``); ``scale`` (``scale.py``) sweeps Gaussian
counts x resolutions, one fresh process per point, and fits how the cost grows. ``cli.py``
parses the command line.

Wall-clock figures depend on the machine and on what else runs on it; compare ratios
measured in one run. Tests never assert them.
"""

from __future__ import annotations


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``ftgspp bench`` (``cli.main``, imported on call). Returns the exit status."""
    from ftgspp.bench.cli import main as cli_main

    return cli_main(argv)
