"""Config hashing: output and logging keys do not count; anything that changes results does."""

from __future__ import annotations

import dataclasses

import torch

from ftgspp.config import TrainConfig
from harness.spec.confighash import HASH_EXCLUDED, config_hash, flatten_config


def _hash(cfg: TrainConfig, synth: dict | None = None) -> str:
    return config_hash(flatten_config(cfg), synth)


def test_flatten_uses_dotted_keys_and_strings() -> None:
    flat = flatten_config(TrainConfig())
    assert flat["lr.means"] == "0.00016"
    assert flat["model.gate"] == "false"
    assert flat["model.max_duration"] == "null"
    assert flat["data.test_cameras"] == '["cam00"]'
    assert HASH_EXCLUDED <= set(flat), "every excluded key must exist in the schema"


def test_hash_ignores_where_and_how_verbosely_a_run_writes() -> None:
    base = TrainConfig()
    other = dataclasses.replace(base, out_dir="/elsewhere", log_every=3, progress=False, diagnostics_figures=False)
    other.tracking.uri = "http://127.0.0.1:5000"
    assert _hash(base) == _hash(other)


def test_hash_changes_with_results_relevant_keys_and_scene_content() -> None:
    base = TrainConfig()
    seen = {_hash(base)}
    for change in (
        dataclasses.replace(base, seed=1),
        dataclasses.replace(base, iterations=10),
        dataclasses.replace(base, model=dataclasses.replace(base.model, gate=True)),
        dataclasses.replace(base, lr=dataclasses.replace(base.lr, scale=3.0)),
    ):
        seen.add(_hash(change))
    seen.add(_hash(base, {"preset": "default", "seed": 0}))
    seen.add(_hash(base, {"preset": "default", "seed": 1}))
    assert len(seen) == 7
    assert _hash(base) == _hash(TrainConfig()), "deterministic"


def test_thread_count_is_part_of_the_hash_and_params() -> None:
    """CPU reductions depend on the thread count, so runs with different counts are different
    experiments; ``threads=0`` (torch's default) is recorded as the count actually in use."""
    base = TrainConfig()
    one, two = dataclasses.replace(base, threads=1), dataclasses.replace(base, threads=2)
    assert _hash(one) != _hash(two)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        assert flatten_config(base)["threads"] == "1"
        assert _hash(base) == _hash(one)
    finally:
        torch.set_num_threads(before)


def test_an_option_added_later_hashes_like_before_at_its_old_behaviour_and_counts_otherwise() -> None:
    """Runs made before ``init.matcher`` / ``init.candidates_per_frame`` / ``init.flow_combine``
    existed keep their hash (resume, `study check`) while those options keep the old behaviour."""
    from harness.spec.confighash import HASH_NEUTRAL

    base = TrainConfig()
    flat = flatten_config(base)
    assert {k: flat[k] for k in HASH_NEUTRAL} == HASH_NEUTRAL  # today's defaults are the neutral values
    before = {k: v for k, v in flat.items() if k not in HASH_NEUTRAL}  # the config as it was
    assert config_hash(flat) == config_hash(before)
    for change in (dict(matcher="dense"), dict(candidates_per_frame=1000), dict(flow_combine="rays")):
        other = dataclasses.replace(base, init=dataclasses.replace(base.init, **change))
        assert _hash(other) != _hash(base), change


def test_a_methods_own_rate_adds_nothing_to_the_params_until_set() -> None:
    """``lr.method`` (a method's own rates, ``DynamicGaussians.LEARNING_RATES``) is empty by default
    and then absent from the flattened config, so a method that brings rates of its own leaves
    every other run's params and hash as they were; ``+lr.method.<key>=`` is a hashed option."""
    from harness.spec.schema import compose, to_train_config

    base = to_train_config(compose([]))
    own = to_train_config(compose(["+lr.method.rgb=0.001"]))
    assert base.lr.method == {} and own.lr.method == {"rgb": 0.001}
    assert not any(k.startswith("lr.method") for k in flatten_config(base))
    flat = flatten_config(own)
    assert flat["lr.method.rgb"] == "0.001"
    assert config_hash(flat) != config_hash(flatten_config(base))
