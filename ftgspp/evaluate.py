"""Evaluation on the held-out cameras over every loaded frame.

Each frame is rendered without colour correction, scored with the metrics of
``ftgspp.image_metrics`` and the per-frame scores are averaged, as the papers do. Two passes:
``evaluate`` (PSNR, SSIM at data range 1 and 2, DSSIM, saved renders) and then
``evaluate_lpips`` (LPIPS when its weights are present), so the trainer can save the
network-free numbers before an optional network metric runs.
A few frames are saved as ``renders/<cam>_<frame>.png`` (ground truth | render).
Both passes, and the trainer's diagnostics after them, take their renders from one
``HeldOutRenders``: each held-out view is rendered once when they fit in memory.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Sequence
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
import torch

from ftgspp.config import TrainConfig
from ftgspp.data.scene import Scene
from ftgspp.errors import InputError
from ftgspp.image_metrics import METRICS, available_metrics, evaluate_images
from ftgspp.lpips.nets import NETS
from ftgspp.methods.base import DynamicGaussians
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


def check_eval_lpips(nets: Sequence[str]) -> None:
    """``InputError`` unless every name in ``nets`` is an LPIPS network."""
    unknown = sorted(set(nets) - set(NETS))
    if unknown:
        raise InputError("eval_lpips", f"unknown LPIPS network(s) {unknown}; choose from {list(NETS)}")


@functools.lru_cache(maxsize=None)
def _loaded_lpips(net: str, device: str) -> torch.nn.Module:
    """The process's one LPIPS model of ``net`` on ``device``: a worker that makes many runs
    loads and verifies the weights once, and keeps the held-out frames' features between runs
    (``LPIPS._reference_features``). Missing weights raise and are not remembered."""
    from ftgspp.lpips import load_lpips

    return load_lpips(net, device=device)


def lpips_models(device: torch.device, nets: Sequence[str] = NETS) -> dict | None:
    """The LPIPS networks ``nets`` when their weights are present, else None (LPIPS keys omitted)."""
    from ftgspp.lpips import WeightsError, missing_message

    check_eval_lpips(nets)
    try:
        return {net: _loaded_lpips(net, str(device)) for net in nets}
    except WeightsError:
        log.warning("%s; LPIPS is left out of the metrics", missing_message())
        return None


def _save_pair(path: Path, gt: np.ndarray, pred: np.ndarray) -> None:
    both = np.concatenate([gt, pred], axis=1)
    cv2.imwrite(str(path), cv2.cvtColor((np.clip(both, 0, 1) * 255 + 0.5).astype(np.uint8), cv2.COLOR_RGB2BGR))


class HeldOutRenders:
    """The model's renders of held-out views (clamped to [0, 1], no colour correction), each
    made once: evaluation, LPIPS and the diagnostics' renders of the same camera and frame
    are the same bits (a render depends only on the model's parameters, the scene's camera
    and time, and these settings). Kept only while all of them fit in ``max_bytes``; else each
    call renders. The model must not change while this object is in use."""

    def __init__(self, model: DynamicGaussians, scene: Scene, cfg: TrainConfig, max_bytes: int = 256 * 2**20):
        self.model, self.scene = model, scene
        self.sh_degree, self.backend = cfg.model.sh_degree, cfg.backend
        self.background = torch.tensor(cfg.background, dtype=torch.float32, device=model.params["means"].device)
        size = sum(scene.cameras[c].height * scene.cameras[c].width * 3 * 4 for c in scene.test_ids) * scene.n_frames
        self.keep = size <= max_bytes
        self._done: dict[tuple[int, int], torch.Tensor] = {}

    def matches(self, model: DynamicGaussians, scene: Scene, sh_degree: int, background: torch.Tensor,
                backend: str) -> bool:
        """Whether renders with these settings are the ones this object holds."""
        return (model is self.model and scene is self.scene and sh_degree == self.sh_degree
                and backend == self.backend and torch.equal(background, self.background))

    @classmethod
    def of(cls, model: DynamicGaussians, scene: Scene, cfg: TrainConfig,
           renders: HeldOutRenders | None) -> HeldOutRenders:
        """``renders`` when given (``ValueError`` unless they are of this model, scene and
        ``cfg``'s settings), else a new object."""
        if renders is None:
            return cls(model, scene, cfg)
        background = torch.tensor(cfg.background, dtype=torch.float32, device=renders.background.device)
        if not renders.matches(model, scene, cfg.model.sh_degree, background, cfg.backend):
            raise ValueError("renders of another model, scene or render settings")
        return renders

    @torch.no_grad()
    def image(self, cam_idx: int, frame: int) -> torch.Tensor:
        """The render [H, W, 3] of camera ``cam_idx`` at frame ``frame``."""
        pred = self._done.get((cam_idx, frame))
        if pred is None:
            out, _ = render_view(self.model, self.scene.cameras[cam_idx], float(self.scene.times[frame]),
                                 self.sh_degree, self.background, self.backend)
            pred = out.image.clamp(0, 1)
            if self.keep:
                self._done[(cam_idx, frame)] = pred
        return pred


# Metrics that need no network (PSNR, SSIM, DSSIM): computed and saved first.
CORE_METRICS = [name for name, m in METRICS.items() if m.lpips_net is None]


@torch.no_grad()
def evaluate(
    model: DynamicGaussians, scene: Scene, cfg: TrainConfig, out_dir: Path, n_saved: int = 3,
    renders: HeldOutRenders | None = None,
) -> tuple[dict[str, float], list[Path]]:
    """PSNR, SSIM and DSSIM averaged over all held-out (camera, frame) pairs, plus a few saved
    renders; returns ``(metrics, saved_pngs)``. LPIPS is separate (``evaluate_lpips``) so that
    an optional network metric runs only after these numbers are on disk. ``renders``: the
    held-out renders to score, shared with later passes (``HeldOutRenders``)."""
    render_dir = out_dir / "renders"
    render_dir.mkdir(parents=True, exist_ok=True)
    return _score(HeldOutRenders.of(model, scene, cfg, renders), CORE_METRICS, None, render_dir, n_saved)


@torch.no_grad()
def evaluate_lpips(model: DynamicGaussians, scene: Scene, cfg: TrainConfig,
                   renders: HeldOutRenders | None = None) -> dict[str, float]:
    """LPIPS (the networks in ``cfg.eval_lpips``, both input conventions) over the held-out frames.

    ``{"lpips_missing": 1.0}`` when the weights are missing (the run records that it was
    scored without LPIPS, so a later run with the weights fills it in); a metric whose network
    cannot take images this small is NaN with a one-line warning (``ftgspp.image_metrics.LPIPS_MIN_SIDE``).
    """
    if not cfg.eval_lpips:
        return {}
    lpips = lpips_models(model.params["means"].device, cfg.eval_lpips)
    if lpips is None:
        return {"lpips_missing": 1.0}
    names = [n for n in available_metrics(lpips) if METRICS[n].lpips_net is not None]
    metrics, _ = _score(HeldOutRenders.of(model, scene, cfg, renders), names, lpips, None, 0)
    metrics.pop("eval_frames")
    return metrics


def _score(renders: HeldOutRenders, names: list[str], lpips: dict | None, render_dir: Path | None,
           n_saved: int) -> tuple[dict[str, float], list[Path]]:
    """Average the ``names`` metrics of every held-out frame's render over frames."""
    scene = renders.scene
    device = renders.background.device
    saved = set(np.linspace(0, scene.n_frames - 1, n_saved).round().astype(int).tolist()) if n_saved else set()
    rows: list[dict[str, float]] = []
    artifacts: list[Path] = []
    for cam_idx in scene.test_ids:
        cam = scene.cameras[cam_idx]
        for f in range(scene.n_frames):
            pred = renders.image(cam_idx, f)
            gt = torch.from_numpy(scene.image(cam_idx, f)).to(device)
            with one_torch_thread():  # metrics independent of how many workers share the machine
                rows.append(evaluate_images(pred, gt, lpips=lpips, names=names))
            if render_dir is not None and f in saved:
                path = render_dir / f"{cam.name}_{f:04d}.png"
                _save_pair(path, gt.cpu().numpy(), pred.cpu().numpy())
                artifacts.append(path)
    metrics = {k: float(np.mean([r[k] for r in rows])) for k in names}
    metrics["eval_frames"] = float(len(rows))
    return metrics, artifacts
