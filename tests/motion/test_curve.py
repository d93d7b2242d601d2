import numpy as np
import pytest

from cmrt.errors import CmrtError
from cmrt.motion.curve import MIN_GAP_S, Cmrt

L = 2.6


def test_zero_params_is_flat_with_equally_spaced_knots():
    c = Cmrt.zero(L)
    np.testing.assert_allclose(c.knot_times_s, [0.52, 1.04, 1.56, 2.08])
    t = np.linspace(0, L, 101)
    assert np.all(c.displacement_m(t) == 0)


@pytest.mark.parametrize("seed", range(5))
def test_any_params_give_ordered_knots_and_round_trip(seed):
    u = np.random.default_rng(seed).normal(scale=3.0, size=8)
    c = Cmrt.from_params(u, L)
    t = np.array(c.knot_times_s)
    assert t[0] >= MIN_GAP_S - 1e-12 and t[-1] <= L - MIN_GAP_S + 1e-12
    assert np.all(np.diff(t) >= MIN_GAP_S - 1e-12)
    np.testing.assert_allclose(c.to_params(), u, atol=1e-9)


def test_spline_passes_knots_and_is_clamped():
    c = Cmrt(L, (0.4, 1.0, 1.3, 2.0), (0.02, -0.03, 0.05, 0.01))
    np.testing.assert_allclose(c.displacement_m(np.array(c.knot_times_s)), c.values_m, atol=1e-12)
    np.testing.assert_allclose(c.displacement_m(np.array([0.0, L])), 0.0, atol=1e-12)
    np.testing.assert_allclose(c.velocity_m_s(np.array([0.0, L])), 0.0, atol=1e-12)
    # velocity is the derivative of displacement
    t = np.linspace(0.1, 2.5, 50)
    fd = (c.displacement_m(t + 1e-6) - c.displacement_m(t - 1e-6)) / 2e-6
    np.testing.assert_allclose(c.velocity_m_s(t), fd, atol=1e-6)
    assert c.displacement_m(-1.0) == 0 and c.displacement_m(L + 1) == 0


def test_json_round_trip_and_bad_input():
    c = Cmrt(L, (0.4, 1.0, 1.3, 2.0), (0.02, -0.03, 0.05, 0.01))
    assert Cmrt.from_json(c.to_json()) == c
    with pytest.raises(CmrtError):
        Cmrt.from_json("{not json")
    with pytest.raises(CmrtError):
        Cmrt.from_json('{"clip_s": 2.6, "knot_times_s": [1, 0.5, 1.5, 2], "values_m": [0, 0, 0, 0]}')
    with pytest.raises(CmrtError):
        Cmrt.from_json('{"clip_s": 2.6}')
