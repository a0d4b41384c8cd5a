"""Configuration schema: plain dataclasses.

These are the single source of truth for every option. Hydra (in ``harness/`` and the
``ftgspp train`` wrapper) composes YAML files in ``conf/`` onto them, so a typo or a wrong
type fails at composition time; library code and tests build them directly.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class DataConfig:
    """Which scene to load and how."""

    path: str = ""  # scene folder; format detected from its contents
    format: str = "auto"  # auto | dynerf | easyvolcap | immersive
    downsample: float = 1.0  # 2 = half resolution
    frame_start: int = 0
    frame_end: int | None = None  # exclusive; None = all frames
    test_cameras: list[str] = field(default_factory=lambda: ["cam00"])
    drop_cameras: list[str] = field(default_factory=list)  # e.g. ["cam13"] for coffee_martini
    cache_dir: str | None = None  # decoded-frame cache; default <scene>/.ftgspp_cache
    fps: float | None = None  # EasyVolcap/Immersive frames: frames per second (default: scene.json or 30)


@dataclass
class ModelConfig:
    """Per-Gaussian representation (docs/design.md §4): a method and its options.

    ``method`` picks the class (``ftgspp.methods``: ``freetime`` for FreeTimeGS and FreeTimeGS++,
    ``stg`` for Spacetime Gaussians, or ``module:Class``); ``name`` labels the configuration
    (``conf/model/<name>.yaml``). The temporal-scale bound and the gate are FreeTimeGS++'s;
    colour correction is the trainer's and applies to every method."""

    name: str = "ftgs"
    method: str = "freetime"
    sh_degree: int = 3
    max_duration: float | None = None  # None: s = exp(d); finite: s = max_duration/6 * sigmoid(d)
    gate: bool = False
    gate_gamma: float = 20.0
    gate_init: float = -1.0
    color_correction: bool = False
    # the iteration colour correction switches on at; None: 10 % of the iterations, the paper's
    # 3,000 of 30,000 (``cc_start``)
    cc_start_iter: int | None = None
    # the colour-correction gauge: "free" (the paper and the official code) or "mean_identity" (the
    # mean of the per-camera transforms pinned to the identity, so they cannot drift together away
    # from the uncorrected held-out camera; an option the collapse study measures)
    cc_gauge: str = "free"
    # the cpu backend's path for this method (``prepare_cpu``, docs/methods.md "Rendering"): True its
    # fused stage, False the generic path (``at_time``, then the shared projection), None the path its
    # runs were first made with (FreeTimeGS fused, STGS generic: their bits). conf/model/stg.yaml
    # sets True; the two paths agree to float rounding, not bit for bit
    fused_stage: bool | None = None
    # the distance the initial scales come from (ftgspp/init/spacing.py): "keyframe" the mean distance to
    # the 3 nearest points of the same keyframe, "union" the RMS distance to the 3 nearest among every
    # keyframe's points together (floored at sqrt(1e-7)), Spacetime Gaussians' public rule; None the
    # rule every method's runs were first made with ("keyframe"). conf/model/stg.yaml sets "union"
    init_spacing: str | None = None


@dataclass
class InitConfig:
    """Point initialization from multi-view matches."""

    keyframe_stride: int = 10
    neighbor_cams: int = 2  # each view is matched to its k nearest cameras
    matcher: str = "sift"  # sift (sparse features) | dense (flow between views: ftgspp/init/dense.py)
    candidates_per_frame: int | None = None  # dense: points kept per keyframe (None: the paper's ~0.5 per pixel)
    # dense: when its points are not trusted (ftgspp/init/dense.py, docs/init.md). "auto": the SIFT matcher
    # (then the budget fill) replaces it for the run when the dense points of a median keyframe reach fewer
    # than dense.COVERAGE_MIN of the cells of a grid over the training views, or when the dense flow's depth
    # at SIFT's keypoints is off SIFT's by a median over dense.AGREEMENT_MAX; "off": always the dense points
    # (the behaviour before this option)
    dense_check: str = "auto"
    max_features: int = 4_000  # SIFT features per image
    ratio_test: float = 0.75
    max_reproj_px: float = 2.0
    velocity: str = "knn"  # knn | flow
    flow_model: str = "dis"  # optical-flow model for velocity=flow (registry in ftgspp/init/flow.py)
    flow_min_weight: float = 1.0  # summed covisibility weight needed to accept a flow velocity
    flow_max_disp: float = 3.0  # accept only |v| dt <= this x local kNN spacing
    flow_combine: str = "mean"  # views' flow displacements: mean (the paper) | lsq | rays (full 3D)
    knn_k: int = 3
    opacity: float = 0.5
    duration: float = 0.1  # seconds
    scale_factor: float = 0.1  # initial scale = factor * kNN spacing
    depth_prior: str = "auto"  # auto (scene bounds or camera baseline) | indoor | outdoor | explicit
    near: float | None = None
    far: float | None = None
    fixed_seed: int | None = None  # compute init once with this seed for all optimisation seeds
    random_points: int = 0  # extra random points in the depth range (0 = none)


@dataclass
class StrategyConfig:
    """MCMC-style relocation of dead Gaussians (count stays fixed)."""

    relocation: str = "mcmc"  # mcmc | exact_copy | partial_copy
    refine_every: int = 100
    refine_start_iter: int = 500
    refine_stop_iter: int = 25_000
    min_opacity: float = 5e-3
    # MCMC rule: clamp the shared opacity "after" computing the scale factor (gsplat 1.5.3,
    # pinned by the official FreeTimeGS++ code: the paper's behaviour) or "before" (gsplat >= 1.6)
    mcmc_clamp: str = "after"
    # Adam moments zeroed at relocation: of the "sources" only (gsplat 1.5.3's ``relocate``, the
    # official code) or of every "moved" Gaussian, sources and destinations (this project before
    # the gsplat parity work)
    reset_moments: str = "sources"
    # Which Gaussians are dead: "opacity" (sigmoid(o) <= min_opacity, the paper's and gsplat's rule)
    # or "clip_opacity" (the opacity the Gaussian reaches anywhere in the clip, o * phi(t), <= min_opacity:
    # a Gaussian whose time lies far outside the clip is never drawn, yet its o keeps it alive)
    dead: str = "opacity"


@dataclass
class LearningRates:
    """Adam learning rates, each × ``scale``; a method's ``EXTENT_SCALED`` ones × the scene extent.

    The fields are the rates every method shares and the options of the built-in methods' own
    rates. A method declares the rates of its own parameters (``DynamicGaussians.LEARNING_RATES``):
    FreeTimeGS's and STGS's are repeated here at the same values, so that ``lr.durations=...`` and
    ``lr.motion=...`` set them and the runs made before keep their config hash; a method added
    since needs no field here, and ``+lr.method.<key>=<rate>`` sets one of its rates."""

    means: float = 1.6e-4
    quats: float = 1e-3
    scales: float = 5e-3
    opacities: float = 5e-2
    sh0: float = 2.5e-3
    shN: float = 1.25e-4
    # FreeTimeGS's own (ftgspp/methods/freetime.py: FreeTimeGaussians.LEARNING_RATES)
    durations: float = 5e-3
    times: float = 1.6e-4
    velocities: float = 1.6e-3
    gates: float = 1e-3
    # Spacetime Gaussians' own (ftgspp/methods/stg.py: SpacetimeGaussians.LEARNING_RATES)
    trbf_center: float = 1e-4
    trbf_scale: float = 0.03
    motion: float = 2.8e-4
    omega: float = 1e-4
    # any other method's own rates by key, where they differ from its LEARNING_RATES (empty: adds
    # nothing to a run's flattened config or hash)
    method: dict[str, float] = field(default_factory=dict)
    cc: float = 1e-3
    means_final_ratio: float = 0.01  # exponential decay of means and velocity over training
    scale: float = 1.0  # global multiplier (stability studies)
    # whether ``scale`` multiplies the colour correction's own rate too: the paper's CC keeps its rate
    # (False); True is an option the collapse study measures
    cc_scaled: bool = False


@dataclass
class LossConfig:
    """Weights of the training loss terms (docs/design.md §4, ``trainer.loss_terms``)."""

    ssim: float = 0.2  # λ in the photometric term (1 − λ) L1 + λ (1 − SSIM)
    lpips: float = 0.0  # LPIPS-Alex; 0.01 on GPU profiles
    opacity_reg: float = 0.01  # FreeTimeGS 4D regulariser
    scale_reg: float = 0.01
    gate_reg: float = 1e-3  # with ModelConfig.gate
    cc_reg: float = 1e-3  # with ModelConfig.color_correction


@dataclass
class TrackingConfig:
    """Where runs are recorded (used by the harness; the library only sees a Tracker)."""

    uri: str = "sqlite:///mlflow.db"  # MLFLOW_TRACKING_URI overrides it
    experiment: str = "ftgspp"


@dataclass
class TrainConfig:
    """Everything one training run needs."""

    data: DataConfig = field(default_factory=DataConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    init: InitConfig = field(default_factory=InitConfig)
    strategy: StrategyConfig = field(default_factory=StrategyConfig)
    lr: LearningRates = field(default_factory=LearningRates)
    loss: LossConfig = field(default_factory=LossConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    profile: str = "quick"
    seed: int = 0
    iterations: int = 30_000
    budget: int = 500_000  # number of Gaussians (fixed by relocation)
    backend: str = "auto"  # auto | reference | cpu | gsplat
    device: str = "auto"  # auto | cpu | cuda
    threads: int = 0  # torch threads; 0 = leave as is (portable mode: 1)
    determinism: str = "default"  # default | portable (same bits on any x86-64; ftgspp/runtime/determinism.py)
    dispatch: str = "native"  # torch CPU kernels as on another CPU: native | avx512 | avx2 | baseline
    sh_degree_interval: int = 1_000
    background: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    random_background: bool = False
    log_every: int = 50
    checkpoint_every: int = 1_000
    diagnostics: bool = True  # lifetime / velocity / x-t / motion-error plots after evaluation
    diagnostics_figures: bool = True  # draw the diagnostics' PNGs (their numbers are measured either way)
    # LPIPS networks scored at evaluation (both input conventions each); VGG16 costs ~10x AlexNet
    eval_lpips: list[str] = field(default_factory=lambda: ["alex", "vgg"])
    out_dir: str = "."
    resume: bool = True
    progress: bool = True


def cc_start(cfg: TrainConfig) -> int:
    """The iteration colour correction switches on at: ``model.cc_start_iter``, or 10 % of the
    iterations when it is None (the paper: 3,000 of 30,000)."""
    if cfg.model.cc_start_iter is not None:
        return int(cfg.model.cc_start_iter)
    return cfg.iterations // 10


def _fill(cls, data: dict):
    """Build dataclass ``cls`` from a (possibly nested) dict, ignoring unknown keys."""
    import dataclasses

    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name not in data:
            continue
        v = data[f.name]
        sub = f.default_factory if f.default_factory is not dataclasses.MISSING else None  # type: ignore[misc]
        if sub is not None and dataclasses.is_dataclass(sub) and isinstance(v, dict):
            v = _fill(sub, v)
        kwargs[f.name] = v
    return cls(**kwargs)


def train_config_from_dict(data: dict) -> TrainConfig:
    """Rebuild a ``TrainConfig`` from ``dataclasses.asdict`` output (e.g. a run's config.json)."""
    return _fill(TrainConfig, data)
