"""The metric registry: one entry per metric a run logs or a report derives.

An entry joins a metric's computation and its presentation: where its value comes from
(``source``: the trainer, held-out evaluation, the diagnostics, the run's resources, MLflow's
system sampler, or a per-run difference of two other metrics), the ``ftgspp.image_metrics``
evaluator that computes it (``compute``, held-out image metrics), its label in tables and
plots, its decimals, which direction is better, whether a claim may test it, whether it is
bit-reproducible, and the smallest effect of interest. Study validation (which metrics a
claim may name), the tables (labels, decimals, best/second-best), aggregation (direction,
derived per-run columns), the budget search and the reports all read this registry, so a
new metric is one ``register(Metric(...))`` call (or one line below); a new image metric is
one function and entry in ``ftgspp.image_metrics.METRICS`` (ftgspp never imports the
harness) plus one ``image_metric(...)`` line here. A test trains a tiny run and fails when it
logs a metric without an entry (tests/harness/test_metric_registry.py).

Names are exact (``psnr``) or ``fnmatch`` patterns for families (``lpips_*``); a name that
matches no entry gets its own name as label, 3 decimals and "higher is better".
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Iterable

import pandas as pd

if TYPE_CHECKING:  # the evaluators load torch: looked up when asked for, not on import
    from ftgspp.image_metrics import ImageMetric

HIGHER, LOWER, NEITHER = "higher", "lower", ""
MEAN, DIFFERENCE = "mean", "difference"
# where a metric's value comes from (DIFFERENCE: ``of[0] - of[1]`` per run, derived by the report)
TRAINER, EVALUATION, DIAGNOSTICS, RESOURCES, SYSTEM = "trainer", "evaluation", "diagnostics", "resources", "system"
SOURCES = (TRAINER, EVALUATION, DIAGNOSTICS, RESOURCES, SYSTEM, DIFFERENCE)


@dataclass(frozen=True)
class Metric:
    """How the harness treats one metric (or a family, when ``name`` is a pattern)."""

    name: str
    label: str = ""  # table/axis label (default: the name)
    decimals: int = 3
    better: str = HIGHER  # higher | lower | "" (a difference between conventions: no better side)
    source: str = TRAINER  # one of SOURCES; DIFFERENCE: ``of[0] - of[1]`` per run (with ``of``)
    of: tuple[str, str] = ("", "")  # the two metrics of a difference
    claimable: bool = True  # a study's claims may test it (exact names only)
    deterministic: bool = True  # same config, seed and domain -> same bits (timings are not)
    computed_by: str = ""  # the key of the ftgspp.image_metrics evaluator computing it (held-out images)
    unit: str = ""  # the unit its label ends with, e.g. "dB"
    phrase: str = ""  # how a sentence names it (default: the label)
    smallest_effect: float | None = None  # smallest effect of interest, in its unit (None: no claim may test it)
    sesoi_scale: str = ""  # the section of docs/sesoi.md that gives its rationale

    def __post_init__(self) -> None:
        if self.source not in SOURCES or self.better not in (HIGHER, LOWER, NEITHER):
            raise ValueError(f"metric '{self.name}': source '{self.source}', better '{self.better}'")
        if self.computed_by and self.source != EVALUATION:
            raise ValueError(f"metric '{self.name}': computed by an image metric, so its source is evaluation")
        if any(self.of) and self.source != DIFFERENCE:
            raise ValueError(f"metric '{self.name}': only a difference names two metrics (of)")

    @property
    def compute(self) -> ImageMetric | None:
        """The ``ftgspp.image_metrics`` evaluator computing it (None: another source)."""
        if not self.computed_by:
            return None
        from ftgspp.image_metrics import METRICS

        return METRICS[self.computed_by]

    @property
    def is_pattern(self) -> bool:
        return any(ch in self.name for ch in "*?[")

    @property
    def aggregation(self) -> str:
        """How runs are combined: ``mean`` of per-run values, or ``difference`` (derived per run)."""
        return DIFFERENCE if self.source == DIFFERENCE else MEAN

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


def image_metric(name: str, label: str, decimals: int, better: str = HIGHER, **fields: Any) -> Metric:
    """The entry of a held-out image metric, computed by ``ftgspp.image_metrics.METRICS[name]``."""
    return Metric(name, label, decimals, better, EVALUATION, computed_by=name, **fields)


def entries() -> tuple[Metric, ...]:
    """Every entry, exact names and families, in registry order."""
    return tuple(_REGISTRY.values())


def registered(name: str) -> Metric | None:
    """The entry for ``name``: exact, else the first matching family pattern, else None."""
    if name in _REGISTRY and not _REGISTRY[name].is_pattern:
        return _REGISTRY[name]
    for m in _REGISTRY.values():
        if m.is_pattern and fnmatch.fnmatch(name, m.name):
            return replace(m, name=name)
    return None


def unregistered(names: Iterable[str]) -> list[str]:
    """The names (sorted) that neither an exact entry nor a family pattern covers."""
    return sorted({n for n in names if registered(n) is None})


def lookup(name: str) -> Metric:
    """The entry for ``name``: exact, else the first matching pattern, else a default."""
    return registered(name) or Metric(name)


def claimable() -> tuple[str, ...]:
    """Exact metric names a claim may test, in registry order."""
    return tuple(m.name for m in _REGISTRY.values() if m.claimable and not m.is_pattern)


def names(source: str | None = None, unit: str | None = None) -> tuple[str, ...]:
    """Exact metric names in registry order, of one ``source`` and/or ``unit`` if given."""
    return tuple(m.name for m in _REGISTRY.values() if not m.is_pattern
                 and source in (None, m.source) and unit in (None, m.unit))


def budget_metrics() -> tuple[str, ...]:
    """What a Gaussian-budget search may judge: the held-out metrics in dB (its threshold is in dB)."""
    return names(EVALUATION, "dB")


def phases() -> tuple[str, ...]:
    """Where a run's time goes, in the order the phases run: its resource metrics in seconds."""
    return names(RESOURCES, "s")


def differences() -> dict[str, tuple[str, str]]:
    """Derived metrics: name -> (a, b), value a - b per run."""
    return {m.name: m.of for m in _REGISTRY.values() if m.aggregation == DIFFERENCE and all(m.of)}


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


def phrase(name: str) -> str:
    """How a sentence names the metric (``held-out PSNR``), else its label."""
    return lookup(name).phrase or label(name)


def lower_is_better(name: str) -> bool:
    return lookup(name).better == LOWER


# --- the metrics of ftgspp's trainer, evaluation and diagnostics ---------------------------
for _m in (
    image_metric("psnr", "PSNR (dB)", 2, unit="dB", phrase="held-out PSNR"),
    image_metric("psnr_cc", "PSNR colour-aligned (dB)", 2, unit="dB", phrase="colour-aligned held-out PSNR"),
    Metric("train_psnr", "training-view PSNR (dB)", 2, unit="dB"),
    Metric("l1", "training-view L1", 5, LOWER, claimable=False),
    # torch's reductions over the Gaussians (the regularisers) change in the last bit with the
    # thread count; l1 and train_psnr are summed by numpy in a fixed order and do not
    Metric("loss", "training loss", 5, LOWER, claimable=False, deterministic=False),
    Metric("diverged_at", "iteration of divergence", 0, NEITHER, claimable=False),  # FAILED runs only
    Metric("cc_mean_delta", "‖mean ΔM‖ of the colour transforms", 4, NEITHER),
    Metric("cc_mean_bias", "‖mean b‖ of the colour transforms", 4, NEITHER),
    image_metric("ssim1", "SSIM (data range 1)", 4),
    image_metric("ssim2", "SSIM (data range 2)", 4),
    image_metric("dssim1", "DSSIM (data range 1)", 4, LOWER),
    image_metric("dssim2", "DSSIM (data range 2)", 4, LOWER),
    image_metric("lpips_alex", "LPIPS-Alex ([-1,1] input)", 4, LOWER),
    image_metric("lpips_vgg", "LPIPS-VGG ([-1,1] input)", 4, LOWER),
    image_metric("lpips_alex_01", "LPIPS-Alex ([0,1] input, 3DGS convention)", 4, LOWER),
    image_metric("lpips_vgg_01", "LPIPS-VGG ([0,1] input, 3DGS convention)", 4, LOWER),
    Metric("eval_frames", "held-out frames scored", 0, NEITHER, EVALUATION, claimable=False),
    # where a run's time goes, phase by phase in this order (``phases``), and its memory
    Metric("init_seconds", "initialisation (s)", 1, LOWER, RESOURCES, claimable=False, deterministic=False, unit="s"),
    Metric("train_seconds", "train time (s)", 1, LOWER, RESOURCES, deterministic=False, unit="s"),
    Metric("eval_seconds", "evaluation (s)", 1, LOWER, RESOURCES, claimable=False, deterministic=False, unit="s"),
    Metric("eval_lpips_seconds", "LPIPS (s)", 1, LOWER, RESOURCES, claimable=False, deterministic=False, unit="s"),
    Metric("diagnostics_seconds", "diagnostics (s)", 1, LOWER, RESOURCES, claimable=False, deterministic=False,
           unit="s"),
    Metric("iters_per_second", "iterations/s", 1, HIGHER, RESOURCES, deterministic=False),
    Metric("peak_rss_mb", "peak RSS (MB)", 0, LOWER, RESOURCES, deterministic=False, unit="MB"),
    Metric("n_gaussians", "#Gaussians", 0, LOWER),
    Metric("n_faded", "Gaussians drawn nowhere in the clip", 0, LOWER),  # opacity there ≤ strategy.min_opacity
    # the trained model's render speed and size (``study measure``: ftgspp/bench/model_fps.py, after training)
    Metric("render_fps_1thread", "render FPS, 1 thread", 1, HIGHER, RESOURCES, deterministic=False),
    Metric("render_fps_all_cores", "render FPS, all cores", 1, HIGHER, RESOURCES, deterministic=False),
    Metric("render_cores", "cores for the all-cores FPS", 0, NEITHER, RESOURCES, claimable=False, deterministic=False),
    Metric("model_bytes", "model size (bytes)", 0, LOWER, RESOURCES, unit="bytes"),
    # what the initial point set is made of (ftgspp/init/quality.py; also each run's init.json)
    # (the measurements against ground truth and the dense check's measures are diagnostics of the init,
    # float64 NumPy/OpenCV reductions whose last bits follow the CPU model even in portable mode: 6.5e-16
    # between two AVX-512 EPYCs, znver4 and znver5, with the models bit for bit equal; `study check`
    # compares them with the evaluation, not the training; what the init decided stays training)
    Metric("init_matcher_dense", "dense matching (1) or SIFT (0)", 0, NEITHER, claimable=False),
    Metric("init_points_total", "real initial points", 0, NEITHER, claimable=False),
    Metric("init_keyframes", "keyframes", 0, NEITHER, claimable=False),
    Metric("init_keyframe_interval_s", "time between keyframes (s)", 3, NEITHER, claimable=False, unit="s"),
    Metric("init_points_per_keyframe_min", "real points, fewest in a keyframe", 0, NEITHER, claimable=False),
    Metric("init_points_per_keyframe_median", "real points per keyframe", 0, NEITHER, claimable=False),
    Metric("init_points_per_keyframe_max", "real points, most in a keyframe", 0, NEITHER, claimable=False),
    Metric("init_real_share", "real points' share of the budget (random points aside)", 2, HIGHER, claimable=False),
    Metric("init_velocity_points_scored", "initial points scored against ground truth", 0, NEITHER, claimable=False),
    Metric("init_velocity_error_moving", "initial velocity error, moving (units/s)", 3, LOWER, claimable=False,
           unit="units/s", source=DIAGNOSTICS),
    Metric("init_velocity_true_speed_moving", "true speed, moving (units/s)", 3, NEITHER, claimable=False,
           unit="units/s", source=DIAGNOSTICS),
    Metric("init_velocity_error_static", "initial velocity error, static (units/s)", 3, LOWER, claimable=False,
           unit="units/s", source=DIAGNOSTICS),
    Metric("init_dense_coverage", "share of the views the dense points cover (init.dense_check)", 2, NEITHER,
           claimable=False, source=DIAGNOSTICS),
    Metric("init_dense_sift_disagreement", "dense flow's median depth gap to SIFT (init.dense_check)", 3, NEITHER,
           claimable=False, source=DIAGNOSTICS),
    Metric("init_dense_fallback", "dense matching not trusted: SIFT instead (1) or dense kept (0)", 0, NEITHER,
           claimable=False),
    Metric("init_depth_error_median", "initial points' relative depth error, median", 4, LOWER, claimable=False,
           source=DIAGNOSTICS),
    Metric("init_depth_error_p90", "initial points' relative depth error, 90th percentile", 4, LOWER,
           claimable=False, source=DIAGNOSTICS),
    # diagnostics (ftgspp.diagnostics.diagnose via the trainer)
    Metric("lifetime_long_on_static", source=DIAGNOSTICS),
    Metric("lifetime_short_on_dynamic", source=DIAGNOSTICS),
    Metric("lifetime_median_fraction", source=DIAGNOSTICS),
    Metric("lifetime_partition_contrast", source=DIAGNOSTICS),
    Metric("lifetime_short_share_dynamic", source=DIAGNOSTICS),
    Metric("lifetime_short_share_static", source=DIAGNOSTICS),
    Metric("lifetime_short_share_transient", source=DIAGNOSTICS),  # scenes with objects that exist for part of the clip
    Metric("lifetime_transient_contrast", source=DIAGNOSTICS),
    # secret 1's stratification: Hartigan's dip of the drawn Gaussians' Δt/T capped at 1
    # (ftgspp/diagnostics/lifetimes.py lifetime_dip); the excess is D minus the uniform null's 95th percentile
    Metric("lifetime_dip", "lifetime dip D (Hartigan)", 4, source=DIAGNOSTICS),
    Metric("lifetime_dip_p", "lifetime dip test p-value", 4, NEITHER, DIAGNOSTICS, claimable=False),
    Metric("lifetime_dip_excess", "lifetime dip above the unimodal null's 95th percentile", 4, source=DIAGNOSTICS),
    Metric("motion_epe_dynamic", better=LOWER, source=DIAGNOSTICS),
    Metric("motion_leak_static", better=LOWER, source=DIAGNOSTICS),
    Metric("motion_role_switch", better=LOWER, source=DIAGNOSTICS),
    # scenes drawn from known Gaussians (the known-size scene with ground_truth: true): the truth's own
    # role switching through the same scoring, and the model's excess over it
    Metric("motion_role_switch_gt", "role switch of the true Gaussians", 4, LOWER, DIAGNOSTICS),
    Metric("motion_role_switch_excess", "role switch above the true Gaussians'", 4, LOWER, DIAGNOSTICS),
    Metric("xt_slice_mae", source=DIAGNOSTICS),
    Metric("flicker_static", source=DIAGNOSTICS),
    Metric("flicker_static_gt", source=DIAGNOSTICS),  # the held-out camera's noise-free frames (gt/clean)
    Metric("flicker_static_gt_noisy", "static flicker of the recorded frames (noise, codec)", 4, NEITHER, DIAGNOSTICS),
    Metric("flicker_static_excess", "static flicker above the noise-free reference", 4, LOWER, DIAGNOSTICS),
    Metric("relocated_total", "Gaussians relocated per run", 0, NEITHER),
    Metric("relocated", "Gaussians relocated at a step", 0, NEITHER, claimable=False),  # a step metric
    Metric("lpips_missing", "scored without LPIPS (weights missing)", 0, NEITHER, EVALUATION, claimable=False,
           deterministic=False),
    # per-run gaps between metric conventions on the same renders (the lpips study)
    Metric("gap_lpips_alex", "LPIPS-Alex: [0,1] − [-1,1] input", 4, NEITHER, DIFFERENCE, ("lpips_alex_01", "lpips_alex")),
    Metric("gap_lpips_vgg", "LPIPS-VGG: [0,1] − [-1,1] input", 4, NEITHER, DIFFERENCE, ("lpips_vgg_01", "lpips_vgg")),
    Metric("gap_ssim", "SSIM: data range 2 − 1", 4, NEITHER, DIFFERENCE, ("ssim2", "ssim1")),
    Metric("psnr_cc_gap", "colour-aligned − raw PSNR (dB)", 2, NEITHER, DIFFERENCE, ("psnr_cc", "psnr"), unit="dB"),
    Metric("gap_dssim", "DSSIM: data range 2 − 1", 4, NEITHER, DIFFERENCE, ("dssim2", "dssim1")),
    # families of metrics without an entry of their own
    Metric("ssim*", decimals=4, source=EVALUATION, claimable=False),
    Metric("lpips*", decimals=4, better=LOWER, source=EVALUATION, claimable=False),
    Metric("dssim*", decimals=4, better=LOWER, source=EVALUATION, claimable=False),
    Metric("gap_*", decimals=4, better=NEITHER, source=DIFFERENCE, claimable=False),
    Metric("motion_*", better=LOWER, source=DIAGNOSTICS, claimable=False),
    Metric("loss*", better=LOWER, claimable=False),
    Metric("epe*", better=LOWER, source=DIAGNOSTICS, claimable=False),
    Metric("system/*", source=SYSTEM, claimable=False, deterministic=False),  # MLflow's system metrics sampler
):
    register(_m)


# --- smallest effects of interest: one per metric, on the metric's own scale ---------------
# What difference in the metric matters to a user of the method, fixed once per metric with
# its rationale in docs/sesoi.md (the section named second) — never a paper's estimate of the
# effect being tested. Fixed on SESOI_FIXED, after the committed runs (issue 44).
SESOI_FIXED = "2026-11-27"
SD_RATIO_SESOI = 1.5  # variance claims: SD(a)/SD(b) within [1/1.5, 1.5] is too small to matter
SD_RATIO_SCALE = "sd-ratio"
SMALLEST_EFFECTS: dict[str, tuple[float, str]] = {
    **{m: (0.2, "psnr") for m in ("psnr", "psnr_cc", "train_psnr", "psnr_cc_gap")},
    **{m: (0.005, "ssim") for m in ("ssim1", "ssim2", "gap_ssim")},
    **{m: (0.0025, "ssim") for m in ("dssim1", "dssim2", "gap_dssim")},
    **{m: (0.005, "lpips") for m in ("lpips_alex", "lpips_vgg", "lpips_alex_01", "lpips_vgg_01", "gap_lpips_alex",
                                     "gap_lpips_vgg")},
    **{m: (0.05, "lifetimes") for m in ("lifetime_long_on_static", "lifetime_short_on_dynamic",
                                        "lifetime_median_fraction", "lifetime_partition_contrast",
                                        "lifetime_short_share_dynamic", "lifetime_short_share_static",
                                        "lifetime_short_share_transient", "lifetime_transient_contrast")},
    **{m: (0.05, "motion") for m in ("motion_epe_dynamic", "motion_leak_static")},
    **{m: (0.015, "role-switch") for m in ("motion_role_switch", "motion_role_switch_gt", "motion_role_switch_excess")},
    **{m: (0.002, "flicker") for m in ("flicker_static", "flicker_static_gt", "flicker_static_gt_noisy",
                                       "flicker_static_excess")},
    **{m: (0.025, "lifetime-dip") for m in ("lifetime_dip", "lifetime_dip_excess")},
}
for _name, (_value, _scale) in SMALLEST_EFFECTS.items():
    register(replace(_REGISTRY[_name], smallest_effect=_value, sesoi_scale=_scale))


def sesoi(metric: str, test: str = "mean") -> tuple[float, str]:
    """The smallest effect of interest of a claim on ``metric`` (an SD ratio for a variance test)
    and the section of docs/sesoi.md that gives its rationale; ValueError when it has none."""
    if test == "variance":
        return SD_RATIO_SESOI, SD_RATIO_SCALE
    m = lookup(metric)
    if m.smallest_effect is None:
        raise ValueError(f"metric '{metric}' has no smallest effect of interest (harness/spec/metrics.py)")
    return m.smallest_effect, m.sesoi_scale
