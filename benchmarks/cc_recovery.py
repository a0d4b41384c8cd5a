"""How close are the learned per-camera colour transforms to the true ones?

The synthetic scene shifts camera c's colours by T_c(x) = x (I + dM_c) + b_c
(gt/color_transforms.json). Training learns R_c(y) = y (I + dM'_c) + b'_c on the model's
own colours y, which equal the true colours only up to one global affine map G (the model
is free to settle on any common colour space). So we fit G once for all training cameras,
by least squares over a grid of colours, minimising |R_c(G(x)) - T_c(x)|, and report the
residual RMS in [0, 1] colour units. The same fit with R_c = identity (no correction) is
the baseline: a correct recovery has a much smaller residual.

    python benchmarks/cc_recovery.py RUN_DIR [RUN_DIR ...]
(RUN_DIR: a training output folder with color_correction.npy, color_bias.npy, config.json)
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from ftgspp.config import DataConfig, train_config_from_dict
from ftgspp.data.load import load_scene


def residual(colors: np.ndarray, learned: list[tuple[np.ndarray, np.ndarray]],
             true: list[tuple[np.ndarray, np.ndarray]]) -> float:
    """RMS of R_c(x A + a) - T_c(x) over cameras and colours, with (A, a) fitted by least squares."""
    rows, rhs = [], []
    n = len(colors)
    xh = np.hstack([colors, np.ones((n, 1))])  # [n, 4]; G(x) = xh @ P with P [4, 3]
    for (N, d), (M, b) in zip(learned, true):
        # R_c(G(x)) = xh P N + d  -> linear in vec(P): kron(N^T, xh) vec(P) (column-major)
        rows.append(np.kron(N.T, xh))
        rhs.append(((colors @ M + b) - d).T.reshape(-1))
    A = np.vstack(rows)
    y = np.concatenate(rhs)
    p, *_ = np.linalg.lstsq(A, y, rcond=None)
    return float(np.sqrt(np.mean((A @ p - y) ** 2)))


def main(run_dirs: list[str]) -> None:
    grid = np.stack(np.meshgrid(*[np.linspace(0.05, 0.95, 6)] * 3, indexing="ij"), -1).reshape(-1, 3)
    for rd in map(Path, run_dirs):
        cfg = train_config_from_dict(json.loads((rd / "config.json").read_text()))
        scene = load_scene(DataConfig(**{**cfg.data.__dict__}))
        gt = json.loads((Path(cfg.data.path) / "gt" / "color_transforms.json").read_text())["cameras"]
        mats, bias = np.load(rd / "color_correction.npy"), np.load(rd / "color_bias.npy")
        names = [scene.cameras[i].name for i in scene.train_ids]
        true = [(np.eye(3) + np.array(gt[n]["dM"]), np.array(gt[n]["b"])) for n in names]
        learned = [(mats[k], bias[k]) for k in range(len(names))]
        identity = [(np.eye(3), np.zeros(3)) for _ in names]
        r_cc, r_id = residual(grid, learned, true), residual(grid, identity, true)
        print(json.dumps({"run": str(rd), "residual_learned": r_cc, "residual_identity": r_id,
                          "ratio": r_cc / r_id}))


if __name__ == "__main__":
    main(sys.argv[1:])
