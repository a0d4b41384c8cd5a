"""The logged training-view L1 and MSE: float64, fixed summation order, any thread count."""

from __future__ import annotations

import math

import torch

from ftgspp.losses import logged_photometric


def test_logged_l1_and_mse_match_an_exact_sum_and_ignore_the_thread_count() -> None:
    g = torch.Generator().manual_seed(0)
    pred, gt = torch.rand(192, 256, 3, generator=g), torch.rand(192, 256, 3, generator=g)  # above torch's grain
    d = (pred - gt).double().flatten().tolist()
    l1, mse = logged_photometric(pred, gt)
    assert math.isclose(l1, math.fsum(abs(x) for x in d) / len(d), rel_tol=1e-14)
    assert math.isclose(mse, math.fsum(x * x for x in d) / len(d), rel_tol=1e-14)
    before = torch.get_num_threads()
    try:
        results = []
        for threads in (1, 2, 3):
            torch.set_num_threads(threads)
            results.append(logged_photometric(pred, gt))
    finally:
        torch.set_num_threads(before)
    assert results[0] == results[1] == results[2]
