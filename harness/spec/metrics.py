"""The metric registry: one entry per metric a run logs or a report derives.

An entry carries everything the harness needs to know about a metric: its label in tables
and plots, its decimals, which direction is better, and how runs are combined
(``mean`` over runs, or ``difference``: a per-run difference of two other metrics, e.g. the
gap between two metric conventions on the same renders). Study validation (which metrics a
claim may name), the tables (labels, decimals, best/second-best), aggregation (direction,
derived per-run columns) and the reports all read this registry, so a new metric is one
``register(Metric(...))`` call (or one line below).

Names are exact (``psnr``) or ``fnmatch`` patterns for families (``lpips_*``); a name that
matches no entry gets its own name as label, 3 decimals and "higher is better".
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass

import pandas as pd

HIGHER, LOWER, NEITHER = "higher", "lower", ""
MEAN, DIFFERENCE = "mean", "difference"


@dataclass(frozen=True)
class Metric:
    """How the harness treats one metric (or a family, when ``name`` is a pattern)."""

    name: str
    label: str = ""  # table/axis label (default: the name)
    decimals: int = 3
    better: str = HIGHER  # higher | lower | "" (a difference between conventions: no better side)
    aggregation: str = MEAN  # mean: per-run values; difference: ``of[0] - of[1]`` per run
    of: tuple[str, str] = ("", "")  # the two metrics of a difference
    claimable: bool = True  # a study's claims may test it (exact names only)
    deterministic: bool = True  # same config, seed and domain -> same bits (timings are not)

    @property
    def is_pattern(self) -> bool:
        return any(ch in self.name for ch in "*?[")

    @property
    def title(self) -> str:
        """The label with its direction arrow (``PSNR (dB) ↑``)."""
        text = self.label or self.name
        return text if self.better == NEITHER else f"{text} {'↓' if self.better == LOWER else '↑'}"


_REGISTRY: dict[str, Metric] = {}


def register(metric: Metric) -> Metric:
    """Add (or replace) a registry entry; returns it."""
    _REGISTRY[metric.name] = metric
    return metric


def unregister(name: str) -> None:
    """Remove an entry (tests that register a metric of their own)."""
    _REGISTRY.pop(name, None)


def lookup(name: str) -> Metric:
    """The entry for ``name``: exact, else the first matching pattern, else a default."""
    if name in _REGISTRY and not _REGISTRY[name].is_pattern:
        return _REGISTRY[name]
    for m in _REGISTRY.values():
        if m.is_pattern and fnmatch.fnmatch(name, m.name):
            return Metric(name, m.label, m.decimals, m.better, m.aggregation, m.of, m.claimable, m.deterministic)
    return Metric(name)


def claimable() -> tuple[str, ...]:
    """Exact metric names a claim may test, in registry order."""
    return tuple(m.name for m in _REGISTRY.values() if m.claimable and not m.is_pattern)


def differences() -> dict[str, tuple[str, str]]:
    """Derived metrics: name -> (a, b), value a - b per run."""
    return {m.name: m.of for m in _REGISTRY.values() if m.aggregation == DIFFERENCE}


def add_differences(df: pd.DataFrame) -> pd.DataFrame:
    """``df`` with a column per derived difference both of whose metrics it has (per run)."""
    return df.assign(**{g: df[a] - df[b] for g, (a, b) in differences().items()
                        if a in df.columns and b in df.columns})


def decimals(name: str) -> int:
    return lookup(name).decimals


def title(name: str) -> str:
    """``PSNR (dB) ↑``: label and direction arrow."""
    return lookup(name).title


def label(name: str) -> str:
    return lookup(name).label or name


def lower_is_better(name: str) -> bool:
    return lookup(name).better == LOWER


# --- the metrics of ftgspp's trainer, evaluation and diagnostics ---------------------------
for _m in (
    Metric("psnr", "PSNR (dB)", 2),
    Metric("psnr_cc", "PSNR colour-aligned (dB)", 2),
    Metric("train_psnr", "training-view PSNR (dB)", 2),
    Metric("l1", "training-view L1", 5, LOWER, claimable=False),
    # torch's reductions over the Gaussians (the regularisers) change in the last bit with the
    # thread count; l1 and train_psnr are summed by numpy in a fixed order and do not
    Metric("loss", "training loss", 5, LOWER, claimable=False, deterministic=False),
    Metric("cc_mean_delta", "‖mean ΔM‖ of the colour transforms", 4, NEITHER),
    Metric("cc_mean_bias", "‖mean b‖ of the colour transforms", 4, NEITHER),
    Metric("ssim1", "SSIM (data range 1)", 4),
    Metric("ssim2", "SSIM (data range 2)", 4),
    Metric("dssim1", "DSSIM (data range 1)", 4, LOWER),
    Metric("dssim2", "DSSIM (data range 2)", 4, LOWER),
    Metric("lpips_alex", "LPIPS-Alex ([-1,1] input)", 4, LOWER),
    Metric("lpips_vgg", "LPIPS-VGG ([-1,1] input)", 4, LOWER),
    Metric("lpips_alex_01", "LPIPS-Alex ([0,1] input, 3DGS convention)", 4, LOWER),
    Metric("lpips_vgg_01", "LPIPS-VGG ([0,1] input, 3DGS convention)", 4, LOWER),
    Metric("train_seconds", "train time (s)", 1, LOWER, deterministic=False),
    Metric("iters_per_second", "iterations/s", 1, deterministic=False),
    Metric("peak_rss_mb", "peak RSS (MB)", 0, LOWER, deterministic=False),
    # where a run's time goes besides training (benchmarks/runs_per_hour.py)
    Metric("init_seconds", "initialisation (s)", 1, LOWER, claimable=False, deterministic=False),
    Metric("eval_seconds", "evaluation (s)", 1, LOWER, claimable=False, deterministic=False),
    Metric("eval_lpips_seconds", "LPIPS (s)", 1, LOWER, claimable=False, deterministic=False),
    Metric("diagnostics_seconds", "diagnostics (s)", 1, LOWER, claimable=False, deterministic=False),
    Metric("n_gaussians", "#Gaussians", 0, LOWER),
    # diagnostics (ftgspp.diagnostics.diagnose via the trainer)
    Metric("lifetime_long_on_static"),
    Metric("lifetime_short_on_dynamic"),
    Metric("lifetime_median_fraction"),
    Metric("lifetime_partition_contrast"),
    Metric("lifetime_short_share_dynamic"),
    Metric("lifetime_short_share_static"),
    Metric("lifetime_short_share_transient"),  # scenes with objects that exist for part of the clip
    Metric("lifetime_transient_contrast"),
    Metric("motion_epe_dynamic", better=LOWER),
    Metric("motion_leak_static", better=LOWER),
    Metric("motion_role_switch", better=LOWER),
    Metric("xt_slice_mae"),
    Metric("flicker_static"),
    Metric("flicker_static_gt"),
    Metric("relocated_total", "Gaussians relocated per run", 0, NEITHER),
    Metric("lpips_missing", "scored without LPIPS (weights missing)", 0, NEITHER, claimable=False, deterministic=False),
    # per-run gaps between metric conventions on the same renders (the lpips study)
    Metric("gap_lpips_alex", "LPIPS-Alex: [0,1] − [-1,1] input", 4, NEITHER, DIFFERENCE, ("lpips_alex_01", "lpips_alex")),
    Metric("gap_lpips_vgg", "LPIPS-VGG: [0,1] − [-1,1] input", 4, NEITHER, DIFFERENCE, ("lpips_vgg_01", "lpips_vgg")),
    Metric("gap_ssim", "SSIM: data range 2 − 1", 4, NEITHER, DIFFERENCE, ("ssim2", "ssim1")),
    Metric("psnr_cc_gap", "colour-aligned − raw PSNR (dB)", 2, NEITHER, DIFFERENCE, ("psnr_cc", "psnr")),
    Metric("gap_dssim", "DSSIM: data range 2 − 1", 4, NEITHER, DIFFERENCE, ("dssim2", "dssim1")),
    # families of metrics without an entry of their own
    Metric("ssim*", decimals=4, claimable=False),
    Metric("lpips*", decimals=4, better=LOWER, claimable=False),
    Metric("dssim*", decimals=4, better=LOWER, claimable=False),
    Metric("gap_*", decimals=4, better=NEITHER, claimable=False),
    Metric("motion_*", better=LOWER, claimable=False),
    Metric("loss*", better=LOWER, claimable=False),
    Metric("epe*", better=LOWER, claimable=False),
    Metric("system/*", claimable=False, deterministic=False),  # MLflow's system metrics sampler
):
    register(_m)
