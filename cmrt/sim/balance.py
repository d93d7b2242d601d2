"""When is balance lost? The monitor the simulator runs at every control step.

A loss of balance is declared when one of these holds (checked in this order):

* ``DIVERGED``: the state or the torques are not finite, or MuJoCo reset an unstable
  simulation - a numerical failure, scored worse than any fall;
* ``BODY_ON_FLOOR``: a body other than the heel/toe points reaches the floor;
* ``COM_LOW``: the CoM is below ``com_height_m`` (standing ~0.97 m, the deepest
  task pose ~0.74 m);
* ``AIRBORNE``: no heel or toe point has touched the floor for ``airborne_s``: a
  planted-feet task has no flight phase;
* ``FOOT_ROLLED``: a foot has rolled more than ``roll_rad`` about its heel or toe: the
  body is toppling over the edge of its support;
* ``CAPTURE_POINT``: the instantaneous capture point xi = c_x + v_x / omega,
  omega = sqrt(g / (c_z - ground)), lies more than ``capture_margin_m`` beyond the
  support the feet on the ground span (heel to toe of every foot that touches it: a
  foot rolled onto its toe comes back down flat while xi is behind the toe). With the
  CoP at most at that edge, xi moves away from it (xi' = omega (xi - p)): the inverted
  pendulum cannot come back without a step. In our push sweeps (docs/controller.md)
  every clip whose capture point left the support fell and every clip that recovered
  kept it inside, so the margin only guards against a one-sample excursion. The check
  does not apply while the hands lean on a prop (the simulator passes an unbounded
  support then): a body pushing a slab is held up by it, not an inverted pendulum.

A foot rocking by millimetres, or the CoP touching an edge, is not a fall: it shows up
in ``min_cop_margin_m`` instead. The checks are pure functions of arrays so that they
can be tested on synthetic states.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from numba import njit

from cmrt.body.character import GRAVITY_M_S2


class FallReason(StrEnum):
    """Why a clip lost balance; the value is the human-readable reason (and the JSON string)."""

    DIVERGED = "numerical blow-up"
    BODY_ON_FLOOR = "a body other than the feet touched the floor"
    COM_LOW = "the CoM dropped too low"
    AIRBORNE = "both feet left the ground"
    FOOT_ROLLED = "a foot rolled over its heel or toe"
    CAPTURE_POINT = "the capture point left the support"


#: Codes in the order the checks run; 0 means balanced.
REASONS: tuple[FallReason, ...] = tuple(FallReason)


@dataclass(frozen=True)
class BalanceLimits:
    """Thresholds of the balance monitor: beyond any of them the character has lost its balance."""

    com_height_m: float = 0.55
    airborne_s: float = 0.03
    roll_rad: float = math.radians(10.0)
    capture_margin_m: float = 0.01


def capture_point_x(com_x: np.ndarray, com_z: np.ndarray, com_vel_x: np.ndarray, ground_z: np.ndarray | float = 0.0
                    ) -> np.ndarray:
    """Instantaneous capture point of the linear inverted pendulum (m)."""
    height = np.maximum(com_z - ground_z, 1e-3)
    return com_x + com_vel_x / np.sqrt(GRAVITY_M_S2 / height)


def check_balance(
    limits: BalanceLimits,
    *,
    finite: np.ndarray,
    lowest_body_z: np.ndarray,
    com_x: np.ndarray,
    com_z: np.ndarray,
    com_vel_x: np.ndarray,
    airborne_for_s: np.ndarray,
    foot_roll_rad: np.ndarray,
    support_lo_x: np.ndarray,
    support_hi_x: np.ndarray,
) -> np.ndarray:
    """Per simulation: 0 if balanced, else 1 + the index in ``REASONS`` of the first failed check.

    Shapes (n,) except ``foot_roll_rad`` (n, 2). ``support_lo_x``/``hi`` span the points on
    the ground (NaN when none is). Compiled (``_first_failed``): it runs at every control step, and
    as numpy it was ~20 calls of a few microseconds each."""
    def f(x):
        return np.ascontiguousarray(x, dtype=np.float64)

    roll = f(foot_roll_rad)
    return _first_failed(np.ascontiguousarray(finite, dtype=np.bool_), f(lowest_body_z), f(com_x), f(com_z),
                         f(com_vel_x), f(airborne_for_s), roll.reshape(roll.shape[0], -1), f(support_lo_x),
                         f(support_hi_x), limits.com_height_m, limits.airborne_s, limits.roll_rad,
                         limits.capture_margin_m)


@njit(cache=True, nogil=True)
def _first_failed(finite, lowest_body_z, com_x, com_z, com_vel_x, airborne_for_s, roll, lo, hi, com_height_m,
                  airborne_s, roll_rad, margin):
    """``check_balance`` per row: the checks in REASONS order. The capture point is ``capture_point_x``'s
    arithmetic operation for operation (NaN heights propagate as ``np.maximum`` lets them), so the
    verdicts are those of the numpy version on every input, NaN included."""
    n = finite.shape[0]
    out = np.zeros(n, np.int64)
    for i in range(n):
        if not finite[i]:
            out[i] = 1
        elif lowest_body_z[i] < 0.0:
            out[i] = 2
        elif com_z[i] < com_height_m:
            out[i] = 3
        elif airborne_s <= airborne_for_s[i]:
            out[i] = 4
        else:
            rolled = False
            for f in range(roll.shape[1]):
                if abs(roll[i, f]) > roll_rad:
                    rolled = True
            if rolled:
                out[i] = 5
            else:
                height = com_z[i] - 0.0
                if height < 1e-3:
                    height = 1e-3
                xi = com_x[i] + com_vel_x[i] / np.sqrt(GRAVITY_M_S2 / height)
                if xi < lo[i] - margin or xi > hi[i] + margin:
                    out[i] = 6
    return out
