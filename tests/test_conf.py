"""``conf/``: YAML holds only the values that differ from the dataclass schema (``ftgspp/config.py``),
and every option of its config groups composes onto ``TrainConfig``.

A value equal to its dataclass default is kept only where it overrides what a file of an
earlier group sets (e.g. a profile's ``data.downsample: 1`` over ``data/dynerf.yaml``'s 2).
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

from omegaconf import OmegaConf

from ftgspp.config import TrainConfig
from harness.spec.schema import CONF_DIR, compose, to_train_config

# config groups in the order conf/train.yaml composes them (a later group overrides an earlier one)
GROUPS = tuple(next(iter(d)) for d in OmegaConf.to_container(OmegaConf.load(CONF_DIR / "train.yaml"))["defaults"]
               if isinstance(d, dict))


def leaves(node: dict, prefix: str = "") -> dict[str, object]:
    """Dotted key -> value of every non-dict value in ``node``."""
    out: dict[str, object] = {}
    for key, value in node.items():
        if isinstance(value, dict):
            out.update(leaves(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def group_values(group: str, path: Path) -> dict[str, object]:
    """The ``TrainConfig`` keys a group file sets, with their values."""
    values = OmegaConf.to_container(OmegaConf.load(path), resolve=False) or {}
    assert isinstance(values, dict)
    values.pop("defaults", None)
    in_global = "# @package _global_" in path.read_text().splitlines()[:1]
    return leaves(values, "" if in_global else f"{group}.")


def restated_defaults(files: dict[str, dict[str, object]], defaults: dict[str, object]) -> list[str]:
    """``group/file: key`` for every value equal to its default that overrides no value a file of
    an earlier group sets (``GROUPS`` order; the files of one group are alternatives)."""
    restated = []
    for name, values in files.items():
        rank = GROUPS.index(name.split("/")[0])
        for key, value in values.items():
            overrides = any(other.get(key, value) != value for o, other in files.items()
                            if GROUPS.index(o.split("/")[0]) < rank)
            if value == defaults[key] and not overrides:
                restated.append(f"{name}: {key}")
    return restated


def conf_files() -> dict[str, dict[str, object]]:
    return {f"{g}/{p.name}": group_values(g, p) for g in GROUPS for p in sorted((CONF_DIR / g).glob("*.yaml"))}


def test_the_check_finds_a_restated_default() -> None:
    defaults = {"iterations": 30_000, "data.downsample": 1.0}
    files = {"profile/a.yaml": {"iterations": 30_000, "data.downsample": 1}, "profile/b.yaml": {"iterations": 30},
             "data/c.yaml": {"data.downsample": 2}, "data/d.yaml": {"data.downsample": 1}}
    # a's default downsample overrides c's (data comes first); b is a's alternative; d overrides nothing
    assert sorted(restated_defaults(files, defaults)) == ["data/d.yaml: data.downsample", "profile/a.yaml: iterations"]


def test_group_files_set_only_schema_keys_and_restate_no_default() -> None:
    defaults = leaves(asdict(TrainConfig()))
    files = conf_files()
    unknown = [f"{name}: {key}" for name, values in files.items() for key in values if key not in defaults]
    assert unknown == []
    assert restated_defaults(files, defaults) == []


def test_every_group_option_composes() -> None:
    options = {g: sorted(p.stem for p in (CONF_DIR / g).glob("*.yaml")) for g in GROUPS}
    for i in range(max(len(o) for o in options.values())):  # each option of each group at least once
        choice = [o[i % len(o)] for o in options.values()]
        overrides = [f"{g}={c}" for g, c in zip(options, choice)] + ["data.path=/scene"]
        cfg = to_train_config(compose(overrides))
        assert cfg.data.path == "/scene" and cfg.profile == choice[GROUPS.index("profile")]


def test_every_profile_trains_the_papers_colour_correction():
    """Issue 54: identity start, regularised toward it (1e-3), the free gauge, CC's own rate not
    multiplied by lr.scale, switched on at 10 % of the iterations: in the composed quick and paper
    configs of FreeTimeGS++, and in the optimiser the trainer builds from the quick one."""
    import numpy as np
    import torch

    from ftgspp.colour_correction import ColorCorrection
    from ftgspp.config import cc_start
    from ftgspp.methods import method_class
    from ftgspp.train_state import make_optimizer

    for profile, iterations in (("quick", 3_000), ("paper", 30_000)):
        cfg = to_train_config(compose([f"profile={profile}", "model=ftgspp"]))
        assert cfg.iterations == iterations and cfg.model.color_correction
        assert cfg.model.cc_gauge == "free" and not cfg.lr.cc_scaled and cfg.loss.cc_reg == 1e-3
        assert cc_start(cfg) == iterations // 10  # the paper: on at iteration 3,000 of 30,000
    quick = to_train_config(compose(["profile=quick", "model=ftgspp"]))
    assert quick.lr.scale == 8.0
    rng = np.random.default_rng(0)
    model = method_class(quick.model.method).from_points(
        rng.random((20, 3)), rng.random((20, 3)), np.zeros(20), np.zeros((20, 3)), np.full(20, 0.1), quick.model,
        quick.init)
    cc = ColorCorrection(3, "cpu", quick.model.cc_gauge)
    assert torch.equal(cc.delta, torch.zeros(3, 3, 3)) and not cc.bias.any()  # the identity at the start
    groups = {g["name"]: g["lr"] for g in make_optimizer(model, cc, quick, extent=1.0).param_groups}
    assert groups["cc"] == quick.lr.cc  # its own rate, while every other rate is x lr.scale
    assert groups["quats"] == quick.lr.quats * quick.lr.scale
