"""``study prune``: kept fractions checked before anything runs, the loss against the unpruned run
paired by seed with its 90% interval, and the smallest fraction settled inside the SESOI."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from ftgspp.errors import InputError
from harness.cli import study
from harness.cli.prune_study import _fractions, settled_loss
from harness.report.prune_page import write_page


def _frame() -> pd.DataFrame:
    rows = []
    unpruned = {0: 32.0, 1: 32.5, 2: 31.8}
    losses = {0.5: (0.01, -0.02, 0.03), 0.25: (0.05, 0.10, 0.02), 0.1: (2.0, 3.1, 2.6)}
    for seed, psnr in unpruned.items():
        rows.append({"seed": seed, "keep": 1.0, "pruned": False, "n_gaussians": 20000, "psnr": psnr,
                     "psnr_cc": psnr + 3, "lpips_alex": 0.02})
        for keep, loss in losses.items():
            rows.append({"seed": seed, "keep": keep, "pruned": True, "n_gaussians": 20000 * keep,
                         "psnr": psnr - loss[seed], "psnr_cc": psnr + 3 - loss[seed], "lpips_alex": 0.03})
    return pd.DataFrame(rows)


def test_the_loss_is_paired_by_seed_with_the_t_interval_and_settles_only_inside_the_sesoi() -> None:
    table = settled_loss(_frame(), sesoi=0.2).set_index("keep")
    for keep, loss in {0.5: (0.01, -0.02, 0.03), 0.25: (0.05, 0.10, 0.02), 0.1: (2.0, 3.1, 2.6)}.items():
        d = np.array(loss)
        half = stats.t.ppf(0.95, len(d) - 1) * d.std(ddof=1) / np.sqrt(len(d))  # the textbook paired interval
        assert table.loc[keep, "loss"] == pytest.approx(d.mean())
        assert (table.loc[keep, "loss_low"], table.loc[keep, "loss_high"]) == pytest.approx((d.mean() - half,
                                                                                             d.mean() + half))
    assert list(table.settled) == [True, True, False]  # 0.25's upper bound 0.15 < 0.2; 0.1 loses 2-3 dB


def test_the_page_names_the_smallest_settled_fraction_and_the_budget_trained_runs(tmp_path: Path) -> None:
    frame = _frame()
    args = argparse.Namespace(name="speed_accuracy", variants=["big"], scenes=["studio"], recover=300,
                              out=tmp_path)
    compare = pd.DataFrame({"variant": ["small", "small"], "n_gaussians": [5000, 5000], "psnr": [31.0, 31.2]})
    page = write_page(args, frame, settled_loss(frame, 0.2), compare, 0.2, ["prune", "speed_accuracy"])
    text = page.read_text()
    assert "**Smallest settled:** keep 0.25, 5,000 Gaussians" in text
    assert "| `small` | 5,000 | 31.10 | 2 |" in text
    assert (page.parent / "curve.png").stat().st_size > 0
    assert len(pd.read_csv(page.parent / "curve.csv")) == len(frame)
    assert list(pd.read_csv(page.parent / "settled.csv").keep) == [1.0, 0.5, 0.25, 0.1]


@pytest.mark.parametrize("keep", ["0", "1.5", "half", ""])
def test_a_bad_kept_fraction_is_one_line_and_exit_status_2_before_anything_runs(keep: str, capsys) -> None:
    with pytest.raises(InputError):
        _fractions(keep)
    with pytest.raises(SystemExit) as stop:
        study.main(["prune", "speed_accuracy", "--variants", "v", "--scenes", "s", "--keep", keep])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--keep" in err
