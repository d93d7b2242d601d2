"""The balance monitor on synthetic states: what is a fall and what is not."""

import math

import numpy as np

from cmrt.balance import REASONS, BalanceLimits, FallReason, capture_point_x, check_balance

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
