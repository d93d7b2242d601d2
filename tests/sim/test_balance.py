"""The balance monitor on synthetic states: what is a fall and what is not."""

import math

import numpy as np

from cmrt.sim.balance import REASONS, BalanceLimits, FallReason, capture_point_x, check_balance

LIMITS = BalanceLimits()


def check(**overrides):
    """One standing simulation (CoM over the middle of [-0.06, 0.18] m, at rest), with overrides."""
    state = dict(finite=True, lowest_body_z=0.5, com_x=0.06, com_z=0.97, com_vel_x=0.0, airborne_for_s=0.0,
                 foot_roll_rad=np.zeros(2), support_lo_x=-0.06, support_hi_x=0.18)
    state.update(overrides)
    arrays = {k: np.atleast_1d(np.asarray(v)) for k, v in state.items()}
    arrays["foot_roll_rad"] = arrays["foot_roll_rad"].reshape(1, 2)
    code = int(check_balance(LIMITS, **arrays)[0])
    return None if code == 0 else REASONS[code - 1]


def test_standing_still_is_balanced():
    assert check() is None


def test_a_millimetre_rock_and_a_cop_at_the_edge_are_not_falls():
    assert check(foot_roll_rad=np.radians([2.0, 2.0])) is None
    assert check(com_x=0.17) is None  # CoM near the toes, at rest: the capture point is inside


def test_capture_point_beyond_the_toes_is_a_fall():
    omega = math.sqrt(9.81 / 0.97)
    assert check(com_vel_x=(0.18 + 0.005 - 0.06) * omega) is None  # within the margin
    assert check(com_vel_x=(0.18 + 0.02 - 0.06) * omega) is FallReason.CAPTURE_POINT
    assert check(com_vel_x=-(0.06 + 0.06 + 0.02) * omega) is FallReason.CAPTURE_POINT  # past the heels


def test_capture_point_formula():
    omega_10 = np.array([9.81 / 100])  # CoM height for omega = 10 1/s
    np.testing.assert_allclose(capture_point_x(np.array([0.1]), omega_10, np.array([1.0])), [0.2])


def test_the_other_checks_and_their_order():
    assert check(foot_roll_rad=np.radians([0.0, 12.0])) is FallReason.FOOT_ROLLED
    assert check(airborne_for_s=0.05) is FallReason.AIRBORNE
    assert check(com_z=0.5) is FallReason.COM_LOW
    assert check(lowest_body_z=-0.001) is FallReason.BODY_ON_FLOOR
    assert check(finite=False, com_z=float("nan")) is FallReason.DIVERGED  # a blow-up wins over everything
    assert check(com_z=0.5, lowest_body_z=-0.01) is FallReason.BODY_ON_FLOOR


def test_no_support_means_no_capture_point_verdict_but_airborne_counts():
    assert check(support_lo_x=np.nan, support_hi_x=np.nan) is None
    assert check(support_lo_x=np.nan, support_hi_x=np.nan, airborne_for_s=0.04) is FallReason.AIRBORNE


def test_vectorised_over_simulations():
    n = 3
    code = check_balance(LIMITS, finite=np.ones(n, bool), lowest_body_z=np.array([0.5, -0.1, 0.5]),
                         com_x=np.full(n, 0.06), com_z=np.full(n, 0.97), com_vel_x=np.array([0.0, 0.0, 2.0]),
                         airborne_for_s=np.zeros(n), foot_roll_rad=np.zeros((n, 2)),
                         support_lo_x=np.full(n, -0.06), support_hi_x=np.full(n, 0.18))
    assert [REASONS[c - 1] if c else None for c in code] == [None, FallReason.BODY_ON_FLOOR, FallReason.CAPTURE_POINT]


def _numpy_check_balance(limits, *, finite, lowest_body_z, com_x, com_z, com_vel_x, airborne_for_s, foot_roll_rad,
                         support_lo_x, support_hi_x):
    """The numpy version check_balance had before it was compiled (issue 17): the reference it must equal."""
    xi = capture_point_x(com_x, com_z, com_vel_x)
    failed = np.empty((len(REASONS) + 1,) + finite.shape, bool)
    failed[0] = False
    failed[1] = ~finite
    failed[2] = lowest_body_z < 0.0
    failed[3] = com_z < limits.com_height_m
    failed[4] = airborne_for_s >= limits.airborne_s
    failed[5] = (np.abs(foot_roll_rad) > limits.roll_rad).any(axis=-1)
    with np.errstate(invalid="ignore"):
        failed[6] = (xi < support_lo_x - limits.capture_margin_m) | (xi > support_hi_x + limits.capture_margin_m)
    return failed.argmax(axis=0)


def test_compiled_check_equals_the_numpy_one_on_random_states_with_nans():
    rng = np.random.default_rng(5)
    n = 4000
    state = dict(finite=rng.random(n) > 0.05, lowest_body_z=rng.normal(0.3, 0.2, n), com_x=rng.normal(0.06, 0.1, n),
                 com_z=rng.normal(0.8, 0.25, n), com_vel_x=rng.normal(0.0, 0.5, n),
                 airborne_for_s=rng.choice([0.0, 0.01, 0.03, 0.05], n), foot_roll_rad=rng.normal(0.0, 0.15, (n, 2)),
                 support_lo_x=rng.normal(-0.06, 0.05, n), support_hi_x=rng.normal(0.18, 0.05, n))
    for key in ("lowest_body_z", "com_x", "com_z", "com_vel_x", "support_lo_x", "support_hi_x"):
        state[key][rng.random(n) < 0.03] = np.nan  # diverged rows, feet off the floor (NaN support)
    state["foot_roll_rad"][rng.random(n) < 0.03, 1] = np.nan
    state["com_z"][:20] = rng.normal(0.0, 1e-3, 20)  # the 1e-3 floor on the pendulum's height
    got = check_balance(LIMITS, **state)
    want = _numpy_check_balance(LIMITS, **state)
    assert np.array_equal(got, want)
    assert set(np.unique(want)) == set(range(len(REASONS) + 1))  # every verdict was exercised
