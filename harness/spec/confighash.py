"""Flatten a resolved training config and hash the part that decides the result.

``flatten_config`` gives the dotted ``key -> str`` mapping logged as MLflow params.
``config_hash`` hashes it minus keys that only say where or how verbosely a run writes
(``HASH_EXCLUDED``) and options added later while they keep their old behaviour (``HASH_NEUTRAL``), plus the synthetic-scene generator args (the scene's content is not
in the training config, only its folder). Two runs with the same hash are the same
experiment, which is what resume relies on.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from typing import Any

from ftgspp.config import TrainConfig
from ftgspp.runtime.determinism import effective_threads

# Keys that never change what a run computes: output location, logging cadence, tracking
# destination, caches, whether the diagnostics' figures are drawn. The thread count is NOT one
# of them: CPU reductions sum in a thread-count dependent order, so it is hashed (as the count
# actually used, see below).
HASH_EXCLUDED = frozenset(
    {
        "out_dir",
        "progress",
        "resume",
        "log_every",
        "checkpoint_every",
        "tracking.uri",
        "tracking.experiment",
        "data.cache_dir",
        "diagnostics_figures",
    }
)

# Options added after runs were made, at the value that reproduces those runs bit for bit: left
# out of the hash while they hold it, so a run made before the option existed is still the same
# experiment (resume, `study check`); any other value is hashed like every option.
HASH_NEUTRAL = {
    "init.matcher": "sift",
    "init.candidates_per_frame": "null",
    "init.flow_combine": "mean",
    "strategy.dead": "opacity",
    "model.method": "freetime",
    "lr.trbf_center": "0.0001",
    "lr.trbf_scale": "0.03",
    "lr.motion": "0.00028",
    "lr.omega": "0.0001",
    "model.fused_stage": "null",
    "model.init_spacing": "null",
}


def _flatten(prefix: str, value: Any, out: dict[str, str]) -> None:
    if isinstance(value, dict):
        for k, v in value.items():
            _flatten(f"{prefix}.{k}" if prefix else str(k), v, out)
    elif isinstance(value, (list, tuple)):
        out[prefix] = json.dumps(list(value))
    elif value is None:
        out[prefix] = "null"
    else:
        out[prefix] = json.dumps(value) if isinstance(value, bool) else str(value)


def flatten_config(cfg: TrainConfig) -> dict[str, str]:
    """Dotted keys of every option, values as strings (``lr.means -> '0.00016'``).

    ``threads=0`` ("leave torch's default"; 1 in portable mode) is replaced by the count
    this process would train with, so the params and the hash say what was used.
    """
    out: dict[str, str] = {}
    _flatten("", dataclasses.asdict(cfg), out)
    out["threads"] = str(effective_threads(cfg.determinism, cfg.threads))
    return out


def config_hash(flat: dict[str, str], synth: dict[str, Any] | None = None) -> str:
    """12 hex digits identifying the experiment (see module docstring)."""
    items = {k: v for k, v in flat.items() if k not in HASH_EXCLUDED and HASH_NEUTRAL.get(k) != v}
    if synth:
        items.update({f"synth.{k}": json.dumps(v, sort_keys=True) for k, v in synth.items()})
    blob = json.dumps(sorted(items.items()), separators=(",", ":"))
    return hashlib.sha256(blob.encode()).hexdigest()[:12]
