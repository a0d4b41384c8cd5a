"""Each method declares its own learning rates (``LEARNING_RATES``); ``LearningRates`` holds the
shared ones and, under the keys their runs recorded, the options of the built-in methods' own.

Oracle: the paper's and the public STGS code's rates as written in docs/design.md §4 and
``conf``'s history (the values ``LearningRates`` had before the methods declared them).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
import pytest

from ftgspp.config import InitConfig, LearningRates, ModelConfig, TrainConfig
from ftgspp.errors import InputError
from ftgspp.methods.freetime import FreeTimeGaussians
from ftgspp.methods.stg import SpacetimeGaussians
from ftgspp.train_state import learning_rates, make_optimizer
from tests.methods.toy_static import StaticGaussians

RECORDED = {  # LearningRates' method rates as runs recorded them (harness/spec/confighash.py HASH_NEUTRAL too)
    "durations": 5e-3, "times": 1.6e-4, "velocities": 1.6e-3, "gates": 1e-3,
    "trbf_center": 1e-4, "trbf_scale": 0.03, "motion": 2.8e-4, "omega": 1e-4,
}  # fmt: skip


class OwnRateGaussians(StaticGaussians):
    """The toy method with a rate of its own for its colour instead of borrowing ``sh0``'s."""

    LR_KEYS: ClassVar[dict[str, str]] = {}
    LEARNING_RATES: ClassVar[dict[str, float]] = {"rgb": 7e-4}


def points(n: int = 5) -> tuple:
    rng = np.random.default_rng(0)
    return (rng.normal(size=(n, 3)), rng.random((n, 3)), rng.random(n), np.zeros((n, 3)), np.full(n, 0.1))


def build(cls, **model) -> object:
    return cls.from_points(*points(), ModelConfig(**model), InitConfig())


def test_the_builtin_methods_declare_the_rates_their_runs_recorded() -> None:
    declared = {**FreeTimeGaussians.LEARNING_RATES, **SpacetimeGaussians.LEARNING_RATES}
    assert declared == RECORDED
    assert {k: getattr(LearningRates(), k) for k in RECORDED} == RECORDED  # the options' defaults


@pytest.mark.parametrize("cls, model", [(FreeTimeGaussians, {"gate": True}), (SpacetimeGaussians, {"sh_degree": 0})])
def test_every_optimised_parameter_takes_its_option(cls, model) -> None:
    m = build(cls, **model)
    lr = LearningRates(**{k: 2 * v for k, v in RECORDED.items()})
    rates = learning_rates(m, lr)
    assert set(rates) == set(m.params)
    for name, rate in rates.items():
        assert rate == getattr(lr, m.LR_KEYS.get(name, name)), name


def test_a_method_added_since_declares_its_own_rate_and_lr_method_sets_it() -> None:
    m = build(OwnRateGaussians, sh_degree=0)
    assert learning_rates(m, LearningRates())["rgb"] == 7e-4
    assert learning_rates(m, LearningRates(method={"rgb": 1e-3}))["rgb"] == 1e-3
    cfg = TrainConfig(lr=LearningRates(scale=2.0, method={"rgb": 1e-3}))
    groups = {g["name"]: g["lr"] for g in make_optimizer(m, None, cfg, extent=3.0).param_groups}
    assert groups["rgb"] == 2e-3 and groups["means"] == LearningRates().means * 2.0 * 3.0


def test_a_rate_nobody_declares_or_a_stray_lr_method_key_is_one_line() -> None:
    class NoRate(StaticGaussians):
        LR_KEYS: ClassVar[dict[str, str]] = {}

    with pytest.raises(InputError, match="no learning rate for the parameter 'rgb'"):
        learning_rates(build(NoRate, sh_degree=0), LearningRates())
    m = build(OwnRateGaussians, sh_degree=0)
    with pytest.raises(InputError, match=r"lr\.method\.rbg.*no rate 'rbg'"):
        learning_rates(m, LearningRates(method={"rbg": 1e-3}))
    with pytest.raises(InputError, match=r"lr\.method\.means.*set lr\.means"):
        learning_rates(m, LearningRates(method={"means": 1e-3}))


def test_frozen_parameters_take_no_rate() -> None:
    m = build(FreeTimeGaussians, gate=False)
    assert "gates" not in learning_rates(m, LearningRates())
