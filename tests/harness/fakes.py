"""A fake trainer and scene generator for harness tests (no real training).

``fake_train`` follows the trainer's contract (``train(cfg, scene, tracker) -> RunResult``
as called through ``harness.run.training.run_training``): it logs a loss curve and a
diagnostic PNG through the tracker and returns metrics that depend on the seed and the
variant. Input errors are the real trainer's: the configuration goes through the same
validation (``Relocator``, so ``strategy.relocation=teleport`` raises ``InputError``),
``lr.scale >= 100`` diverges, and a file ``crash_seed<N>`` in the working directory makes
the run with that seed crash once (the file is consumed). ``FAKE_TRAIN_SLEEP`` (seconds)
makes every run take that long; ``FAKE_TRAIN_SPANS`` (a file) gets a line ``start end`` (time
stamps) per run; ``FAKE_TRAIN_NOISE=1`` makes a run say what the real trainer's runs say
(``noise``).
"""

from __future__ import annotations

import logging
import math
import os
import sys
import time
import warnings
from pathlib import Path

from ftgspp.config import TrainConfig
from ftgspp.runtime.determinism import determinism_domain
from ftgspp.strategy import Relocator
from ftgspp.tracker import RunResult, Tracker

LOSS_STEPS = 40  # per-step loss values each run logs


def fake_psnr(cfg: TrainConfig) -> float:
    scene = 0.0 if "fast" not in cfg.data.path else -1.5
    return 25.0 + scene + 0.5 * cfg.model.color_correction + 0.25 * cfg.seed + 0.01 * cfg.budget / 100 \
        + 0.001 * cfg.iterations


def fake_train(cfg: TrainConfig, out_dir: Path, tracker: Tracker) -> RunResult:
    Relocator(cfg.strategy)  # the trainer's own validation: unknown policy -> InputError
    domain = determinism_domain(cfg.determinism, cfg.threads)  # tagged like the real trainer does
    tracker.set_tags({f"determinism.{k}": v for k, v in domain.items()})
    crash = Path(f"crash_seed{cfg.seed}")
    if crash.exists():
        crash.unlink()
        raise RuntimeError(f"simulated crash of seed {cfg.seed}")
    if cfg.lr.scale >= 100:
        tracker.log_metrics({"loss": 1.0}, step=0)
        tracker.log_metrics({"loss": math.nan}, step=1)
        return RunResult("FAILED", {"train_seconds": 0.1}, failure="diverged", out_dir=out_dir)
    start = time.time()
    time.sleep(float(os.environ.get("FAKE_TRAIN_SLEEP", "0")))
    if os.environ.get("FAKE_TRAIN_NOISE"):
        noise(cfg)
    if spans := os.environ.get("FAKE_TRAIN_SPANS"):
        with open(spans, "a") as fh:  # one write, appended: runs in other processes add theirs
            fh.write(f"{start} {time.time()}\n")
    for step in range(LOSS_STEPS):
        tracker.log_metrics({"loss": 1.0 / (step + 1), "l1": 0.5 / (step + 1)}, step=step)
    diag = Path(out_dir) / "diagnostics"
    diag.mkdir(parents=True, exist_ok=True)
    (diag / "diagnostics.json").write_text("{}")
    tracker.log_artifact(diag / "diagnostics.json", "diagnostics")
    if cfg.diagnostics_figures:  # as the trainer: only the figures depend on it
        (diag / "lifetime_hist.png").write_bytes(b"\x89PNG\r\n\x1a\n fake")
        tracker.log_artifact(diag / "lifetime_hist.png", "diagnostics")
    psnr = fake_psnr(cfg)
    metrics = {
        "psnr": psnr,
        "ssim1": 0.9 + 0.001 * cfg.seed,
        "ssim2": 0.95,
        "dssim1": 0.05,
        "dssim2": 0.025,
        "lpips_alex": 0.2 - 0.001 * cfg.seed,
        "lpips_alex_01": 0.18 - 0.001 * cfg.seed,
        "train_seconds": 1.0 + cfg.iterations / 1000 + cfg.budget / 10_000,
        "iters_per_second": 100.0,
        "peak_rss_mb": 500.0,
        "n_gaussians": float(cfg.budget),
    }
    return RunResult("FINISHED", metrics, out_dir=out_dir)


def noise(cfg: TrainConfig) -> None:
    """What a real run says besides its result: the initialiser's INFO records (in this process),
    a training child process's output as it copies it to stderr (an INFO and a WARNING record and
    a progress bar), a NumPy RuntimeWarning, and a warning record of this process."""
    import numpy as np

    log = logging.getLogger("ftgspp.init")
    log.info("init: frame 0: 9 views, 10 pairs, 522 matches, 521 epipolar inliers, 467 points")
    sys.stderr.write("[2026-11-27 12:00:00,000][ftgspp.init][INFO] - init: frame 10: 9 views (child)\n"
                     "train:  50%|#####     | 15/30\rtrain: 100%|##########| 30/30\n"
                     f"[2026-11-27 12:00:01,000][ftgspp.evaluate][WARNING] - child warning, seed {cfg.seed}\n")
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        np.log(np.zeros(1))  # RuntimeWarning: divide by zero encountered in log
    logging.getLogger("ftgspp.evaluate").warning("in-process warning, seed %d", cfg.seed)


def fake_generate(out: Path, layout: str, preset: str, seed: int, **extra: object) -> Path:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "scene.txt").write_text(f"{layout} {preset} {seed} {sorted(extra.items())}")
    return out


# A two-variant study of the fake trainer, for report and index tests (tests/harness/test_claims_report.py,
# test_report_currency.py).
MINI_STUDY = {
    "name": "mini",
    "question": "Does colour correction help the fake trainer?",
    "baseline": "baseline",
    "variants": {"baseline": [], "cc": ["model.color_correction=true"]},
    "metrics": ["psnr"],
    "plots": [],
    "claims": [
        {"id": "cc_mean", "claim": "CC raises PSNR.", "metric": "psnr", "test": "mean", "a": "cc", "b": "baseline",
         "scenes": ["easy"], "expect": "higher", "pair": "none"},
        {"id": "cc_spread", "claim": "CC lowers the spread.", "metric": "psnr", "test": "variance", "a": "cc",
         "b": "baseline", "scenes": ["easy"], "expect": "lower"},
        {"id": "motion", "claim": "Not logged by the fake.", "metric": "flicker_static", "test": "mean", "a": "cc",
         "b": "baseline", "scenes": ["easy"], "expect": "lower", "group": "extension"},
        {"id": "psnr_ssim", "claim": "Some pair has equal PSNR but different SSIM.", "metric": "psnr",
         "versus": "ssim1", "test": "decoupled", "expect": "exists", "scenes": ["easy"],
         "among": ["baseline", "cc"]},
    ],
    "profiles": {
        "quick": {"seeds": 3, "overrides": ["profile=smoke"], "run_seconds": 5, "command": "study run mini",
                  "scenes": [{"name": "easy", "synth": {"preset": "studio", "seed": 0}}]},
        "paper": {"seeds": 2, "overrides": ["profile=paper"], "scenes": [{"name": "real", "overrides": ["data.path=/x"]}]},
    },
}
