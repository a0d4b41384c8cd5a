"""Evaluation on the held-out cameras over every loaded frame.

Each frame is rendered without colour correction, scored with every metric of
``ftgspp.metrics.evaluate_images`` (PSNR, SSIM at data range 1 and 2, DSSIM, LPIPS when
its weights are present), and the per-frame scores are averaged, as the papers do.
A few frames are saved as ``renders/<cam>_<frame>.png`` (ground truth | render).
"""

from __future__ import annotations

from pathlib import Path

import logging
from contextlib import contextmanager

import cv2
import numpy as np
import torch

from ftgspp.config import TrainConfig
from ftgspp.data.scene import Scene
from ftgspp.metrics import evaluate_images
from ftgspp.model import FreeTimeGaussians
from ftgspp.view import render_view

log = logging.getLogger("ftgspp.evaluate")


@contextmanager
def one_torch_thread():
    """Run torch on one CPU thread inside the block.

    Convolutions (SSIM windows, LPIPS networks) sum in a thread-count dependent order, so
    the same images could score differently in the 8th decimal under ``study run --jobs 2``
    than under ``--jobs 1``. One thread makes every metric bit-identical across both.
    """
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def lpips_models(device: torch.device) -> dict | None:
    """Both LPIPS networks when their weights are present, else None (LPIPS keys omitted)."""
    from ftgspp.lpips import WeightsError, load_all, missing_message

    try:
        return load_all(device=device)
    except WeightsError:
        log.warning("%s; LPIPS is left out of the metrics", missing_message())
        return None


def _save_pair(path: Path, gt: np.ndarray, pred: np.ndarray) -> None:
    both = np.concatenate([gt, pred], axis=1)
    cv2.imwrite(str(path), cv2.cvtColor((np.clip(both, 0, 1) * 255 + 0.5).astype(np.uint8), cv2.COLOR_RGB2BGR))


@torch.no_grad()
def evaluate(
    model: FreeTimeGaussians, scene: Scene, cfg: TrainConfig, out_dir: Path, n_saved: int = 3
) -> tuple[dict[str, float], list[Path]]:
    """Average metrics over all held-out (camera, frame) pairs; returns ``(metrics, saved_pngs)``."""
    device = model.params["means"].device
    background = torch.tensor(cfg.background, dtype=torch.float32, device=device)
    lpips = lpips_models(device)
    render_dir = out_dir / "renders"
    render_dir.mkdir(parents=True, exist_ok=True)
    saved = set(np.linspace(0, scene.n_frames - 1, n_saved).round().astype(int).tolist())
    rows: list[dict[str, float]] = []
    artifacts: list[Path] = []
    for cam_idx in scene.test_ids:
        cam = scene.cameras[cam_idx]
        for f in range(scene.n_frames):
            out, _ = render_view(model, cam, float(scene.times[f]), cfg.model.sh_degree, background, cfg.backend)
            pred = out.image.clamp(0, 1)
            gt = torch.from_numpy(scene.image(cam_idx, f)).to(device)
            with one_torch_thread():  # metrics independent of how many workers share the machine
                rows.append(evaluate_images(pred, gt, lpips=lpips))
            if f in saved:
                path = render_dir / f"{cam.name}_{f:04d}.png"
                _save_pair(path, gt.cpu().numpy(), pred.cpu().numpy())
                artifacts.append(path)
    keys = rows[0].keys()
    metrics = {k: float(np.mean([r[k] for r in rows])) for k in keys}
    metrics["eval_frames"] = float(len(rows))
    return metrics, artifacts
