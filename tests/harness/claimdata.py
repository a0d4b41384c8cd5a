"""Constructed runs and claims for the claim and verdict tests (``test_claims``, ``test_verdict_protocol``)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from harness.spec.study_schema import ClaimSpec


def runs(values: dict[tuple[str, str], np.ndarray], metric: str = "psnr") -> pd.DataFrame:
    """A per-run frame like ``report.results.runs_frame``: {(variant, scene): per-seed values}."""
    rows = [{"variant": v, "scene": s, "seed": i, "status": "FINISHED", metric: float(x)}
            for (v, s), xs in values.items() for i, x in enumerate(xs)]
    return pd.DataFrame(rows)


def claim(sesoi: float = 0.1, **kw: object) -> ClaimSpec:
    """A mean claim ``cc`` − ``baseline`` on PSNR, expecting higher; ``kw`` overrides any field."""
    base = {"id": "c", "statement": "s", "metric": "psnr", "test": "mean", "expect": "higher", "a": "cc",
            "b": "baseline", "sesoi": sesoi}
    return ClaimSpec(**{**base, **kw})
