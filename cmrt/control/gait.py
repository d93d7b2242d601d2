"""Yu's tracked walking: the keyed gait's contact schedule and swing, for the controller (``cmrt.motion.gait``).

The gait says when each foot swings; while one does, it has no support rows (the stance foot carries the body)
and its leg tracks the gait's own joint angles at full weight (``kernel.S_SWING_TRACKED``: the keyed knee bends,
so the foot can rise). Its heel is also steered, as a task-space objective, along the gait's swing path placed
on the actual stance heel: the reference's swing-heel-to-stance-heel vector at the same instant, as eq. 3.2 places
the reference's foot-to-CoM vector on the actual feet. The CoM and CoP targets stay Yu's (eq. 3.2-3.4,
``cmrt.control.references``): the command gives none.

A push moves the swing's landing, as a person's does (the gait's adjustment): until the foot may touch down
(``ADJUST_UNTIL``), the capture point's error against the reference motion's (each from the stance ankle; the
state as the balance feedback feels it, 0.1 s old, against the reference of that moment) grown to touchdown moves
the landing by ``stepping.STEP_ADJUST_GAIN`` of it beyond ``ADJUST_DEAD_M``, as a footstep plan's
step is moved. The later steps are placed from the foot where it landed. (People place the foot where the body's
state in mid-swing calls for: Wang and Srinivasan 2014.)

The swing ends when the foot touches the floor late enough in its swing (``TOUCHDOWN_AFTER``); one that has not
by the end of its swing keeps being lowered, gently, until it does. The next step lifts off at its keyed time,
never before the step before it has landed.

Exposes the stepping supervisor's interface (``update``, ``support``, ``landing_span``, ``swinging`` and its
records), so ``cmrt.sim.simulate`` runs either.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cmrt.body.character import GRAVITY_M_S2
from cmrt.control import kernel
from cmrt.control.stepping import (
    NO_SWING,
    LandingWatch,
    StepCommand,
    StepConfig,
    stance_support,
    step_adjustment_m,
    swinging_feet,
    with_landing,
)

TOUCHDOWN_AFTER = 0.85  # the swing foot on the floor counts as landed after this fraction of its swing (as a
# footstep plan's, cmrt.control.stepping.PLANNED_TOUCHDOWN_AFTER)
SWING_TRACKED = 1.0  # kernel.S_SWING_TRACKED of a swing: the leg follows the gait's angles at full weight
LATE_DEPTH_M = 0.02  # a swing foot still up after its swing is aimed this far into the floor; it is lowered to
SET_DOWN_FROM = 0.7  # that depth from this fraction of the swing on. Measured in yu-walk: aimed at the floor
# itself, the first and the closing step hovered 5 mm up for 0.15 s and landed late (the foot's objective weighs
# little against the momentum objectives; releasing the swing leg's joint tracking did not bring it down)

ADJUST_UNTIL = TOUCHDOWN_AFTER  # a push moves a swing's landing until the foot may touch down. Measured in yu-walk
# (+-150 N x 0.1 s at 1.5, 2.0, 2.5 s): until half the swing, as a plan's step, +150 N at 1.5 s still fell - the
# push came at a third of the swing and was felt, 0.1 s later, at half; until 0.65-0.8 of it the foot landed
# 3.5 cm off its moved target; until 0.85 all six were successes
ADJUST_DEAD_M = 0.15  # errors (grown to touchdown) smaller than this move no step. Measured in the unpushed
# yu-walk: up to 0.10 m (its keyed CoM is kinematic, not a pendulum's), so with a plan's 0.05 m every step moved
# 1-3 cm and the footprints drifted 3.9 cm ahead of the gait's in six steps; with 0.15 m the unpushed walk moves
# none and the six +-150 N pushes are successes (0.10 m: 2 cm drift; 0.12 m: 6 mm)


@dataclass(frozen=True)
class KeyedSwings:
    """What the tracker takes of a keyed gait (``cmrt.sim.simulate`` makes it from ``cmrt.motion.gait.Gait``)."""

    foot: np.ndarray  # (steps,) the foot of each step: 0 right, 1 left
    lift_off_s: np.ndarray  # (steps,) when each lifts off
    swing_s: float  # lift-off to touchdown
    feet_paths: Callable[[np.ndarray], tuple[np.ndarray, ...]]  # times (k,) -> each ankle's x, z (k, 2) in the
    # gait's frame, their rates and accelerations (cmrt.motion.gait.feet_paths)
    foot_to_com_x_m: np.ndarray | None = None  # (steps, 2) the reference motion's CoM from each ankle, at every
    foot_to_com_vel_x_m_s: np.ndarray | None = None  # physics step, and its rate (references.MotionCom); None: no
    step_s: float = 0.002  # adjustment. The physics step those are sampled at
    delay_s: float = 0.0  # the balance feedback's delay: the adjustment is made from the state felt this long ago


class GaitTracker:
    """Per-simulation swing state of a batch of n clips following one keyed gait."""

    def __init__(self, n: int, gait: KeyedSwings, heel_to_ankle_m: tuple[float, float], foot_length_m: float):
        self.gait = gait
        self.heel_to_ankle_m = heel_to_ankle_m  # the heel point's centre from the ankle (x, z), foot flat
        self.foot_length_m = foot_length_m  # heel point to toe point
        self.swing = np.full(n, NO_SWING)
        self.next_step = np.zeros(n, int)
        self.t0 = np.zeros(n)
        self.target_heel_x = np.zeros(n)  # where the swing heel lands
        self.adjust_m = np.zeros(n)  # how far a push moved the swing's landing from the gait's
        self.step_times: list[list[float]] = [[] for _ in range(n)]  # lift-off times
        self.footprints: list[list[tuple[int, float, float]]] = [[] for _ in range(n)]  # (foot, time, heel x)
        self.placement_error_m: list[list[tuple[float, float]]] = [[] for _ in range(n)]  # (touchdown s, landed
        # - targeted heel m): the step's length against the gait's, from where the stance foot stood
        self.flat = LandingWatch(n)

    def _relative(self, j: int, s: np.ndarray) -> tuple[np.ndarray, ...]:
        """The gait's swing ankle relative to its stance ankle along step j at progress ``s`` (k,): x, z and their
        rates and accelerations (the stance ankle is still: its path's derivatives are zero)."""
        g = self.gait
        t = g.lift_off_s[j] + np.clip(s, 0.0, 1.0) * g.swing_s
        x, z, vx, vz, ax, az = g.feet_paths(t)
        f = g.foot[j]
        return x[:, f] - x[:, 1 - f], z[:, f], vx[:, f], vz[:, f], ax[:, f], az[:, f]

    def update(self, ids: np.ndarray, time_s: float, com_x: np.ndarray, com_z: np.ndarray, momentum_x: np.ndarray,
               ang_momentum_y: np.ndarray, mass_kg: np.ndarray, contact: np.ndarray, point_x: np.ndarray,
               cmrt: tuple[np.ndarray, np.ndarray] | None = None,
               felt: tuple[np.ndarray, ...] | None = None) -> StepCommand:
        """Advance simulations ``ids`` to ``time_s`` (a control step): touchdowns, lift-offs, and the swing's
        command. ``contact`` (k, 4) and ``point_x`` (k, 4): heel_r, toe_r, heel_l, toe_l on the floor / their x.
        ``felt``: (com_x, com_z, momentum_x, ang_momentum_y) the delay ago, as the supervisor's (None: now); the
        CMRT is not used (the stepping supervisor's signature)."""
        g = self.gait
        self._touchdowns(ids, time_s, contact, point_x)
        idle = np.flatnonzero(self.swing[ids] < 0)
        for r in idle:
            sim, j = ids[r], self.next_step[ids[r]]
            if j < g.foot.size and time_s >= g.lift_off_s[j] - 1e-9:
                self.swing[sim] = g.foot[j]
                self.t0[sim] = time_s
                self.next_step[sim] = j + 1
                self.step_times[sim].append(time_s)
                self.adjust_m[sim] = 0.0
        felt = felt if felt is not None else (com_x, com_z, momentum_x, ang_momentum_y)
        self._adjust(ids, time_s, felt[0], felt[1], felt[2] / mass_kg, point_x)
        return self._command(ids, time_s, point_x)

    def _adjust(self, ids: np.ndarray, time_s: float, com_x: np.ndarray, com_z: np.ndarray, vel_x: np.ndarray,
                point_x: np.ndarray) -> None:
        """The gait's adjustment of swings until ``ADJUST_UNTIL``: the felt capture point's error against the
        reference motion's, both from the stance ankle, grown to touchdown, moves the landing."""
        g = self.gait
        if g.foot_to_com_x_m is None:
            return
        k_felt = min(max(int(round((time_s - g.delay_s) / g.step_s)), 0), g.foot_to_com_x_m.shape[0] - 1)
        for r in np.flatnonzero(self.swing[ids] >= 0):
            sim = ids[r]
            elapsed = time_s - self.t0[sim]
            if elapsed > ADJUST_UNTIL * g.swing_s:
                continue
            stance = 1 - self.swing[sim]
            omega = np.sqrt(GRAVITY_M_S2 / max(float(com_z[r]), 0.5))
            ankle = point_x[r, 2 * stance] - self.heel_to_ankle_m[0]
            xi = com_x[r] + vel_x[r] / omega - ankle
            xi_ref = g.foot_to_com_x_m[k_felt, stance] + g.foot_to_com_vel_x_m_s[k_felt, stance] / omega
            error_td = (xi - xi_ref) * np.exp(omega * (g.swing_s - elapsed + g.delay_s))
            self.adjust_m[sim] = step_adjustment_m(float(error_td), ADJUST_DEAD_M)

    def _touchdowns(self, ids: np.ndarray, time_s: float, contact: np.ndarray, point_x: np.ndarray) -> None:
        self.flat.update(ids, time_s, contact)
        for r in np.flatnonzero(self.swing[ids] >= 0):
            sim = ids[r]
            foot = self.swing[sim]
            late_enough = time_s - self.t0[sim] >= TOUCHDOWN_AFTER * self.gait.swing_s
            if late_enough and (contact[r, 2 * foot] or contact[r, 2 * foot + 1]):
                heel = float(point_x[r, 2 * foot])
                self.footprints[sim].append((int(foot), time_s, heel))
                self.flat.landed(sim, int(foot), time_s)
                self.placement_error_m[sim].append((time_s, heel - float(self.target_heel_x[sim])))
                self.swing[sim] = NO_SWING

    def _command(self, ids: np.ndarray, time_s: float, point_x: np.ndarray) -> StepCommand:
        k = ids.size
        swing = self.swing[ids]
        target = np.zeros((k, kernel.N_SWING))
        for r in np.flatnonzero(swing >= 0):
            sim = ids[r]
            foot, j = swing[r], self.next_step[sim] - 1
            s = np.array([(time_s - self.t0[sim]) / self.gait.swing_s])
            dx, z, vx, vz, ax, az = (float(v[0]) for v in self._relative(j, s))
            stance_heel = point_x[r, 2 * (1 - foot)]
            nominal = float(self._relative(j, np.ones(1))[0][0])  # the gait's landing from the stance heel
            reach = StepConfig.max_step_m if self.adjust_m[sim] > 0 else StepConfig.max_back_step_m
            adjust = float(np.clip(nominal + self.adjust_m[sim], -reach, reach)) - nominal
            u = min(max(s[0], 0.0), 1.0)  # a push's adjustment eases in along the swing
            target[r, 0] = stance_heel + dx + adjust * u * u * (3 - 2 * u)  # heel point x: heels sit alike
            target[r, 3] = vx + adjust * 6 * u * (1 - u) / self.gait.swing_s
            target[r, 6] = ax + adjust * (6 - 12 * u) / self.gait.swing_s**2 * (0.0 < u < 1.0)
            late = s[0] > 1.0
            span = (1.0 - SET_DOWN_FROM) * self.gait.swing_s
            u = min(max((s[0] - SET_DOWN_FROM) / (1.0 - SET_DOWN_FROM), 0.0), 1.0)  # the set-down: a cubic ease
            down, ddown, dddown = u * u * (3 - 2 * u), 6 * u * (1 - u), 6 - 12 * u if 0.0 < u < 1.0 else 0.0
            target[r, 1] = -LATE_DEPTH_M if late else z + self.heel_to_ankle_m[1] - LATE_DEPTH_M * down
            target[r, 4] = 0.0 if late else vz - LATE_DEPTH_M * ddown / span
            target[r, 7] = 0.0 if late else az - LATE_DEPTH_M * dddown / span**2
            target[r, kernel.S_SWING_TRACKED] = SWING_TRACKED
            self.target_heel_x[sim] = stance_heel + nominal + adjust
        nan = np.full(k, np.nan)
        return StepCommand(swing.astype(float), target, nan, nan.copy(), nan.copy())

    def support(self, ids: np.ndarray, point_x: np.ndarray, lo: np.ndarray, hi: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
        """The stance foot's [heel, toe] while the other swings (``lo``/``hi`` elsewhere)."""
        return stance_support(self.swing[ids], point_x, lo, hi)

    def landing_span(self, ids: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For the balance monitor: the support with the footprint the swing foot is heading for."""
        return with_landing(self.swing[ids], self.target_heel_x[ids], self.foot_length_m, lo, hi)

    def swinging(self, ids: np.ndarray) -> np.ndarray:
        """(k, 2) bool: which foot of each simulation swings now."""
        return swinging_feet(self.swing[ids])
