import json

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


@pytest.mark.parametrize("seed", range(3))
def test_a_cmrt_in_two_axes_shares_its_knots_and_round_trips(seed):
    """12 parameters: the 8 of a one-axis CMRT, then the cross values; the knots are the first axis's."""
    u = np.random.default_rng(seed).normal(scale=2.0, size=12)
    c = Cmrt.from_params(u, L)
    one = Cmrt.from_params(u[:8], L)
    assert c.axes == 2 and one.axes == 1
    assert c.knot_times_s == one.knot_times_s and c.values_m == one.values_m
    np.testing.assert_allclose(c.cross_values_m, 0.05 * u[8:], rtol=1e-15)
    np.testing.assert_allclose(c.to_params(), u, atol=1e-9)
    assert c.along() == one and c.cross.knot_times_s == c.knot_times_s
    t = np.linspace(0.0, L, 57)
    np.testing.assert_array_equal(c.displacement_m(t), one.displacement_m(t))  # the first axis is untouched
    np.testing.assert_allclose(c.cross.displacement_m(np.array(c.knot_times_s)), c.cross_values_m, atol=1e-12)
    np.testing.assert_allclose(c.cross.velocity_m_s(np.array([0.0, L])), 0.0, atol=1e-12)  # clamped as the first
    again = Cmrt.from_json(c.to_json())
    assert again == c and set(c.to_dict()) == {"clip_s", "knot_times_s", "values_m", "cross_values_m"}
    assert "cross_values_m" not in one.to_dict()  # a one-axis CMRT's form is as it was


def test_the_zero_cmrt_in_two_axes_and_a_one_axis_cross_are_flat():
    c = Cmrt.zero(L, 2)
    assert c.axes == 2 and c.cross_values_m == (0.0,) * 4 and c.to_params().size == 12
    assert np.all(Cmrt.zero(L).cross.displacement_m(np.linspace(0, L, 31)) == 0.0)


@pytest.mark.parametrize("bad, says", [
    ({"cross_values_m": [0.01, 0.02, 0.03]}, "cross_values_m must be a list of 4"),
    ({"cross_values_m": [0.01, 0.02, 0.03, 2.0]}, r"in \[-1, 1\] m"),
    ({"cross_values_m": [0.01, 0.02, 0.03, "x"]}, "cross_values_m"),
    ({"across_m": [0.0] * 4}, "not a CMRT object"),
])
def test_a_bad_cross_axis_is_refused_with_one_line(bad, says):
    obj = {**Cmrt(L, (0.4, 1.0, 1.3, 2.0), (0.02, -0.03, 0.05, 0.01)).to_dict(), **bad}
    with pytest.raises(CmrtError, match=says) as exc:
        Cmrt.from_json(json.dumps(obj))
    assert "\n" not in str(exc.value)


def test_neither_8_nor_12_parameters_are_refused():
    for n in (4, 10, 16):
        with pytest.raises(CmrtError, match="expected 8 CMRT parameters"):
            Cmrt.from_params(np.zeros(n), L)
