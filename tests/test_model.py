"""FreeTimeGaussians: motion, temporal activation, gate and effective lifetime."""

import math

import numpy as np
import pytest
import torch
from scipy.optimize import brentq

from ftgspp.config import InitConfig, ModelConfig
from ftgspp.methods.freetime import FreeTimeGaussians, duration_to_param


def make_model(n=4, **cfg):
    rng = np.random.default_rng(0)
    return FreeTimeGaussians.from_points(
        rng.normal(size=(n, 3)), rng.uniform(size=(n, 3)), rng.uniform(0, 1, n),
        rng.normal(size=(n, 3)), np.full(n, 0.1), ModelConfig(**cfg), InitConfig(),
    )


def test_linear_motion_and_init_values():
    m = make_model()
    p = m.params
    g = m.at_time(0.7)
    expected = p["means"] + p["velocities"] * (0.7 - p["times"])[:, None]
    torch.testing.assert_close(g.means, expected)
    # initial opacity 0.5, duration 0.1 s, scale 0.1 * spacing, colour from SH DC
    torch.testing.assert_close(m.base_opacity(), torch.full((4,), 0.5))
    torch.testing.assert_close(m.temporal_scale(), torch.full((4,), 0.1))
    torch.testing.assert_close(g.scales, torch.full((4, 3), 0.01))


@pytest.mark.parametrize("max_duration", [None, 1.0])
def test_temporal_activation_is_gaussian_in_time(max_duration):
    m = make_model(max_duration=max_duration)
    s = m.temporal_scale()
    t = 0.3
    a = torch.exp(-0.5 * ((t - m.params["times"]) / s) ** 2)
    torch.testing.assert_close(m.temporal_opacity(t), a)
    torch.testing.assert_close(m.at_time(t).opacities, m.base_opacity() * a)
    # at the temporal centre a(t) = 1
    for i in range(4):
        assert m.temporal_opacity(m.params["times"][i].item()).detach()[i].item() == pytest.approx(1.0, abs=1e-6)


def test_bounded_duration_never_exceeds_max():
    m = make_model(max_duration=1.0)
    with torch.no_grad():
        m.params["durations"].fill_(50.0)
    assert torch.all(m.temporal_scale() <= 1.0 / 6.0 + 1e-7)


def test_gate_one_is_persistent_and_gate_zero_is_plain_activation():
    m = make_model(gate=True, max_duration=1.0)
    far = 100.0  # far from every temporal centre: a(t) ~ 0
    with torch.no_grad():
        m.params["gates"].fill_(5.0)  # sigmoid(20 * 5) -> 1
    torch.testing.assert_close(m.temporal_opacity(far), torch.ones(4))
    with torch.no_grad():
        m.params["gates"].fill_(-5.0)  # -> 0
    plain = make_model(gate=False, max_duration=1.0)
    torch.testing.assert_close(m.temporal_opacity(0.4), plain.temporal_opacity(0.4), atol=1e-12, rtol=0)
    # the default gate logit -1 gives g = sigmoid(-20), i.e. (almost) the plain activation
    fresh = make_model(gate=True, max_duration=1.0)
    assert fresh.gate().max().item() == pytest.approx(1 / (1 + math.exp(20)), rel=1e-5)


@pytest.mark.parametrize("threshold", [0.01, 0.1, 0.3])
def test_lifetime_matches_numeric_search(threshold):
    m = make_model(n=6, max_duration=1.0)
    with torch.no_grad():
        m.params["opacities"].copy_(torch.tensor([-3.0, -1.0, 0.0, 1.0, 2.0, 4.0]))
        m.params["durations"].copy_(torch.linspace(-2, 2, 6))
    o = m.base_opacity().detach().numpy().astype(np.float64)
    s = m.temporal_scale().detach().numpy().astype(np.float64)
    mu = m.params["times"].detach().numpy().astype(np.float64)
    dt = m.lifetimes(threshold).detach().numpy()
    for i in range(6):
        f = lambda t: o[i] * math.exp(-0.5 * ((t - mu[i]) / s[i]) ** 2) - threshold  # noqa: E731
        if o[i] <= threshold:
            assert dt[i] == 0
            continue
        hi = brentq(f, mu[i], mu[i] + 50 * s[i])  # o a(t) = θ on each side of μt
        lo = brentq(f, mu[i] - 50 * s[i], mu[i])
        assert dt[i] == pytest.approx(hi - lo, rel=1e-4)


def test_duration_param_roundtrip():
    assert math.exp(duration_to_param(0.1, None)) == pytest.approx(0.1)
    d = duration_to_param(0.1, 1.0)
    assert 1.0 / 6.0 / (1 + math.exp(-d)) == pytest.approx(0.1)
