"""The fall monitor of a batch of clips: per simulation whether and when it fell (and why), judged every
control step by ``cmrt.sim.balance.check_balance``, and protective mode, which the fallen play out in.

``FallMonitor`` keeps the verdicts and the state a fallen clip is judged by; ``ProtectiveMode`` turns the
fallen simulations' joints into passive springs and dampers (docs/controller.md). Both are used by
``cmrt.sim.simulate`` (the Python loop calls ``FallMonitor.check``; the compiled tick writes the same arrays).
"""

from __future__ import annotations

import numpy as np

from cmrt.body.character import character
from cmrt.sim.balance import BalanceLimits, check_balance

# Protective mode after a fall: a passive spring-damper about the pose at the fall, per joint (a fraction of
# the motor's torque limit per rad and per rad/s): muscle tone, no goal. It is MuJoCo's own joint stiffness and
# damping, set per simulation (``ProtectiveMode``), so the implicit integrator carries the damping: as torques held
# over a control step (v0.2) the damper was unstable on the light distal joints (ankle c T / I = 3.77 > 2:
# ankles chattering at 79-100 rad/s, feet slapping the floor at 5-15 body weights). docs/controller.md.
PROTECTIVE_STIFFNESS_PER_RAD = 0.1
PROTECTIVE_DAMPING_PER_RAD_S = 0.1


class ProtectiveMode:
    """Protective mode: the fallen simulations' joints become passive springs and dampers about the pose they
    fell in - muscle tone without a goal, so it cannot add energy (the CoM only goes down) - as MuJoCo's per-
    simulation joint stiffness, damping and spring pose, integrated by MuJoCo (its damping implicitly). Their
    motors are off."""

    def __init__(self, batch, limits_nm: np.ndarray):
        m = character().model
        joints = m.actuator_trnid[:, 0]
        self.dofs, self.qpos_adr = m.jnt_dofadr[joints], m.jnt_qposadr[joints]
        self.joints, self.limits, self.batch = joints, limits_nm, batch
        self.fields: tuple | None = None

    def fall(self, sims: np.ndarray, qpos: np.ndarray) -> None:
        """Simulations ``sims`` (batch rows) fell in pose ``qpos`` (their rows)."""
        if self.fields is None:  # per-simulation values from the first fall on (the others keep the model's)
            self.fields = tuple(self.batch.expand(k) for k in ("jnt_stiffness", "dof_damping", "qpos_spring"))
        stiffness, damping, spring = self.fields
        for row, q in zip(sims, qpos, strict=True):
            stiffness[row, self.joints] = PROTECTIVE_STIFFNESS_PER_RAD * self.limits
            damping[row, self.dofs] = PROTECTIVE_DAMPING_PER_RAD_S * self.limits
            spring[row, self.qpos_adr] = q[self.qpos_adr]


class FallMonitor:
    """The balance monitor's verdicts per simulation: whether and when it fell (and why), the state it is
    judged by, the pose protective mode holds, and the step it stops at (moved on a fall)."""

    def __init__(self, n: int, n_act: int, nq: int, run_steps: int, limits: BalanceLimits, dt: float,
                 control_dt: float):
        self.limits, self.dt, self.control_dt = limits, dt, control_dt  # what a fall is; the step, the control step
        self.code = np.zeros(n, int)  # 0: standing; else 1 + index into REASONS
        self.step = np.full(n, -1)
        self.hold = np.zeros((n, n_act))  # protective mode: the pose at the fall
        self.qpos = np.zeros((n, nq))  # the state a fallen clip is judged by
        self.speed_m_s = np.zeros(n)
        self.capture_x = np.full(n, np.nan)  # the capture point and CoM velocity at the fall (its direction)
        self.com_vel_x = np.full(n, np.nan)
        self.airborne_for_s = np.zeros(n)
        self.end = np.full(n, run_steps)

    def check(self, ids: np.ndarray, k: int, *, ok: np.ndarray,
              grounded: np.ndarray, support_lo_x: np.ndarray, support_hi_x: np.ndarray, lowest_body_z: np.ndarray,
              qpos: np.ndarray, com: np.ndarray, com_vel_x: np.ndarray, roll: np.ndarray,
              time_s: np.ndarray) -> np.ndarray:
        """Run the monitor on simulations ``ids`` at step ``k``; returns the mask of those that fell now."""
        self.airborne_for_s[ids] = np.where(grounded, 0.0, self.airborne_for_s[ids] + self.control_dt)
        finite = ok & np.all(np.isfinite(qpos), axis=1) & (np.abs(time_s - k * self.dt) < 1e-9)
        code = check_balance(
            self.limits, finite=finite, lowest_body_z=lowest_body_z, com_x=com[:, 0], com_z=com[:, 2],
            com_vel_x=com_vel_x, airborne_for_s=self.airborne_for_s[ids], foot_roll_rad=roll,
            support_lo_x=support_lo_x, support_hi_x=support_hi_x,
        )
        new = (code > 0) & (self.code[ids] == 0)
        self.code[ids[new]] = code[new]
        return new

    def fell(self, sims: np.ndarray, k: int, qpos: np.ndarray, act: np.ndarray, speed_m_s: np.ndarray,
             end: np.ndarray) -> None:
        """Simulations ``sims`` fell at step ``k`` in state ``qpos`` (their rows): keep what they are judged by
        and the pose protective mode holds; they stop stepping at ``end``."""
        self.step[sims] = k
        self.hold[sims] = qpos[:, act]
        self.qpos[sims] = qpos[:, : self.qpos.shape[1]]
        self.speed_m_s[sims] = speed_m_s
        self.end[sims] = end
