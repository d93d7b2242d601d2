"""A keyed walking gait: the reference motion Yu's thesis tracks (its figure 4.8), made from a gait's keys.

Yu tracks motion-capture walking with the ``yu`` references (eq. 3.2-3.5). We have no capture data, so the motion
is made from the events a gait is keyed by:

* footprints: ``steps`` forward steps of ``step_length_m`` (the first from feet together, the right foot first),
  then the trailing foot brought beside the leading one - the footprints of the ``walk`` task's plan;
* timing: the first lift-off at ``first_step_s``, each swing ``swing_s`` long, ``double_support_s`` between a
  touchdown and the next lift-off;
* the swing foot: flat, its ankle eased from footprint to footprint (quintic in x) and lifted on a bell
  ``lift_m`` high;
* the pelvis: at the walking speed, over the stance foot at every mid-swing as it is over the feet standing (the
  stand pose's offset), speeding up from rest and slowing to rest over the feet together with bounded
  acceleration; ``crouch_m`` lower while walking than standing; the trunk at the stand pose's pitch.

Every frame's leg angles then follow from two-link leg inverse kinematics (hip, knee) with the foot flat (ankle):
the reference's stance foot stays exactly where it was put. Arms, lumbar and neck hold the stand pose.

What the controller takes from it (``cmrt.control.gait``): the joint angles to track, the CoM relative to each
foot (eq. 3.2's r_f(u), through ``cmrt.control.references.motion_com``), and when each foot swings with its heel's
path relative to the stance heel's.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from cmrt.body.character import Character, character
from cmrt.errors import CmrtError
from cmrt.motion.reference import smoothstep5

CHECK_STEP_S = 0.01  # check_gait's grid
STOP_DECEL_M_S2 = 0.6  # the keyed pelvis slows to a stop no faster than this: the CoP it needs is h a / g = 5.5 cm
# ahead of the CoM. Keyed to arrive over the feet by the closing mid-swing (PCHIP through the mid-swing keys), it
# asked 2.2 m/s^2 there with 0.4 s swings - a CoP 20 cm ahead, past the toes - and the walk fell after its stop
SETTLE_S = 0.6  # after the last touchdown the pelvis eases back over the feet and up to standing height
CROUCH_IN_S = 0.4  # before the first lift-off the pelvis eases down to walking height over this long at least
GAIT_PARAMS: dict[str, float] = {  # the task parameters a gait is keyed by (a task has a gait when gait_steps > 0)
    "gait_steps": 0.0,  # forward steps before the closing one (0: no gait)
    "gait_step_length_m": 0.2,  # footprint to footprint
    "gait_swing_s": 0.6,  # lift-off to touchdown
    "gait_double_support_s": 0.2,  # touchdown to the next lift-off
    "gait_first_step_s": 0.5,  # the first lift-off
    "gait_lift_m": 0.05,  # the swing heel's highest point above the floor
    "gait_crouch_m": 0.03,  # the pelvis this much lower while walking (straight legs cannot reach a split stance)
}


@dataclass(frozen=True)
class Gait:
    """A gait's keys (``GAIT_PARAMS``)."""

    steps: int
    step_length_m: float
    swing_s: float
    double_support_s: float
    first_step_s: float
    lift_m: float
    crouch_m: float

    @staticmethod
    def from_params(params: dict[str, float]) -> Gait | None:
        if params.get("gait_steps", 0.0) <= 0:
            return None
        p = {**GAIT_PARAMS, **params}
        return Gait(steps=int(round(p["gait_steps"])), step_length_m=p["gait_step_length_m"],
                    swing_s=p["gait_swing_s"], double_support_s=p["gait_double_support_s"],
                    first_step_s=p["gait_first_step_s"], lift_m=p["gait_lift_m"], crouch_m=p["gait_crouch_m"])

    @property
    def n_steps(self) -> int:
        """Every step, the closing one included."""
        return self.steps + 1

    def foot(self, j: int) -> int:
        """The foot of step j: 0 right (first), 1 left."""
        if j == self.steps:  # the closing step: the trailing foot
            return 1 - (self.steps - 1) % 2
        return j % 2

    def lift_off_s(self, j: int) -> float:
        return self.first_step_s + j * (self.swing_s + self.double_support_s)

    def touchdown_s(self, j: int) -> float:
        return self.lift_off_s(j) + self.swing_s

    @property
    def speed_m_s(self) -> float:
        """The walking speed: a step's length per step's time."""
        return self.step_length_m / (self.swing_s + self.double_support_s)

    @property
    def speed_up_s(self) -> tuple[float, float]:
        """When the pelvis starts to speed up from rest, and for how long: over the two steps' time before the
        second mid-swing, so it is over the stance foot from then on (earlier than 0: ``check_gait`` refuses)."""
        period = self.swing_s + self.double_support_s
        return self.lift_off_s(1) + 0.5 * self.swing_s - 2 * period, 2 * period

    @property
    def stop_s(self) -> tuple[float, float]:
        """When the pelvis starts to slow down, and for how long: a quintic ease whose largest deceleration is
        ``STOP_DECEL_M_S2`` (1.875 v / T), ending over the feet together."""
        v = self.speed_m_s
        ease = 1.875 * v / STOP_DECEL_M_S2
        last_mid = self.lift_off_s(self.steps - 1) + 0.5 * self.swing_s  # over the last forward step's stance foot
        return last_mid + (self.step_length_m - 0.5 * v * ease) / v, ease

    @property
    def end_s(self) -> float:
        """When the reference is back at the stand pose: the pelvis at rest and the crouch gone."""
        stop, ease = self.stop_s
        return max(self.touchdown_s(self.steps) + SETTLE_S, stop + ease)

    def footprints_m(self) -> np.ndarray:
        """(n_steps + 1, 2): each foot's ankle x (from its start) after step j - 1 (row 0: the start)."""
        feet = np.zeros((self.n_steps + 1, 2))
        for j in range(self.n_steps):
            feet[j + 1] = feet[j]
            feet[j + 1, self.foot(j)] = self.step_length_m * (min(j, self.steps - 1) + 1)
        return feet


@dataclass(frozen=True)
class GaitMotion:
    """The keyed gait at given times: the humanoid's q, qd, qdd (n, nv) and the feet (ankle x, z per foot,
    (n, 2) each, and their x, z rates), in the frame where the feet start at x = 0."""

    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    ankle_x_m: np.ndarray
    ankle_z_m: np.ndarray
    ankle_vel_x_m_s: np.ndarray
    ankle_vel_z_m_s: np.ndarray
    ankle_acc_x_m_s2: np.ndarray
    ankle_acc_z_m_s2: np.ndarray


def _swing(s: np.ndarray) -> tuple[np.ndarray, ...]:
    """A swing's progress along x (quintic) and its lift (a bell 64 s^3 (1 - s)^3, 1 at mid-swing), with their
    first and second derivatives in s; both start and end at rest."""
    s = np.clip(s, 0.0, 1.0)
    x, dx, ddx = smoothstep5(s)
    lift = 64.0 * s**3 * (1 - s) ** 3
    dlift = 192.0 * s**2 * (1 - s) ** 2 * (1 - 2 * s)
    ddlift = 384.0 * s * (1 - s) * (1 - 5 * s + 5 * s**2)
    return x, dx, ddx, lift, dlift, ddlift


def feet_paths(gait: Gait, t_s: np.ndarray, ankle_z0_m: float) -> tuple[np.ndarray, ...]:
    """Ankle x, z per foot (n, 2) and their first and second time derivatives, at times ``t_s``."""
    t = np.asarray(t_s, float)
    n = t.size
    x, z = np.zeros((n, 2)), np.full((n, 2), ankle_z0_m)
    vx, vz, ax, az = (np.zeros((n, 2)) for _ in range(4))
    prints = gait.footprints_m()
    for f in range(2):
        x[:, f] = prints[0, f]
    for j in range(gait.n_steps):
        f, t0, T = gait.foot(j), gait.lift_off_s(j), gait.swing_s
        a, b = prints[j, f], prints[j + 1, f]
        after = t >= t0
        s = (t - t0) / T
        p, dp, ddp, h, dh, ddh = _swing(s)
        x[after, f] = (a + (b - a) * p)[after]
        during = after & (s <= 1.0)
        vx[during, f] = ((b - a) * dp / T)[during]
        ax[during, f] = ((b - a) * ddp / T**2)[during]
        z[during, f] = (ankle_z0_m + gait.lift_m * h)[during]
        vz[during, f] = (gait.lift_m * dh / T)[during]
        az[during, f] = (gait.lift_m * ddh / T**2)[during]
    return x, z, vx, vz, ax, az


def _eased(u: np.ndarray) -> np.ndarray:
    """The integral of ``smoothstep5`` from 0 to u (u past 1 goes on at rate 1; before 0 it is 0): the distance a
    speed eased in over unit time has covered."""
    v = np.clip(u, 0.0, 1.0)
    return 2.5 * v**4 - 3.0 * v**5 + v**6 + np.maximum(u - 1.0, 0.0)


def pelvis_path(gait: Gait, t_s: np.ndarray, offset_x_m: float, height_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Pelvis x and z at times ``t_s``.

    x: the stand pose's ``offset_x_m`` ahead of the feet, then at the walking speed L / (swing + double support),
    which puts it over the stance ankle (plus that offset) at every mid-swing. The speed eases in (quintic) over
    the two steps' time before the second mid-swing - so over the first distance L - and eases out at
    ``gait.stop_time_s`` so that the pelvis comes to rest over the feet together, its deceleration never above
    ``STOP_DECEL_M_S2``. z: ``crouch_m`` lower while walking, eased in and out as the square of a quintic
    (standing, the knees are straight, and a knee's angle grows as the square root of the hip's drop: a linear
    ease would start the knee at an infinite rate)."""
    t = np.asarray(t_s, float)
    v, (start, ease_in), (stop, ease_out) = gait.speed_m_s, gait.speed_up_s, gait.stop_s
    px = offset_x_m + v * (ease_in * _eased((t - start) / ease_in) - ease_out * _eased((t - stop) / ease_out))
    crouch_s = min(gait.first_step_s - CROUCH_IN_S, start)  # the knees bend before the pelvis moves: standing
    # straight, the legs are at full reach
    down = smoothstep5((t - crouch_s) / (gait.first_step_s - crouch_s))[0]
    up = smoothstep5((t - gait.touchdown_s(gait.steps)) / SETTLE_S)[0]
    return px, height_m - gait.crouch_m * (down * (1.0 - up)) ** 2


def leg_ik(dx: np.ndarray, dz: np.ndarray, thigh_m: float, shank_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Absolute thigh angle and knee angle (rad, MuJoCo's +y: positive swings the thigh back and bends the knee)
    that put the ankle at (dx, dz) from the hip. Out of reach, the leg is straight toward it."""
    dist = np.hypot(dx, dz)
    cos_knee = (dist**2 - thigh_m**2 - shank_m**2) / (2 * thigh_m * shank_m)
    knee = np.arccos(np.clip(cos_knee, -1.0, 1.0))
    toward = np.arctan2(-dx, -dz)  # the hip-to-ankle direction as a leg angle
    return toward - np.arctan2(shank_m * np.sin(knee), thigh_m + shank_m * np.cos(knee)), knee


@dataclass(frozen=True)
class StandFrame:
    """What the keyed gait takes from the stand pose: the leg's lengths and where the ankle and pelvis stand."""

    thigh_m: float
    shank_m: float
    ankle_z_m: float  # the ankle's height
    offset_x_m: float  # the pelvis ahead of the ankles
    height_m: float  # the pelvis's height

    @property
    def reach_m(self) -> float:
        return self.thigh_m + self.shank_m


def stand_frame(ch: Character, stand_qpos: np.ndarray) -> StandFrame:
    """The stand pose's ``StandFrame`` (MuJoCo's forward kinematics; feet together, knees straight)."""
    m = ch.model
    d = mujoco.MjData(m)
    d.qpos[:] = stand_qpos
    mujoco.mj_kinematics(m, d)
    pelvis, ankle = d.xpos[1], d.xpos[ch.foot_bodies[0]]
    foot = ch.foot_bodies[0]  # its body sits at the ankle, the shank's at the knee
    return StandFrame(thigh_m=float(-m.body_pos[foot - 1, 2]), shank_m=float(-m.body_pos[foot, 2]),
                      ankle_z_m=float(ankle[2]), offset_x_m=float(pelvis[0] - ankle[0]), height_m=float(pelvis[2]))


def gait_motion(gait: Gait, ch: Character, stand_qpos: np.ndarray, t_s: np.ndarray) -> GaitMotion:
    """The keyed gait at times ``t_s`` (see the module docstring), from the stand pose ``stand_qpos`` (feet
    together and flat, knees straight): the reference a ``gait`` task tracks."""
    t = np.atleast_1d(np.asarray(t_s, float))
    frame = stand_frame(ch, stand_qpos)
    q = _pose(gait, ch, stand_qpos, t, frame)
    # rates by central differences RATE_STEP_S wide, the same whatever times are asked for (the angles are smooth
    # functions of smooth paths: measured against 0.1 ms differences, within 1e-4 of the largest rate)
    q_ahead, q_behind = (_pose(gait, ch, stand_qpos, t + h, frame) for h in (RATE_STEP_S, -RATE_STEP_S))
    qd = (q_ahead - q_behind) / (2 * RATE_STEP_S)
    qdd = (q_ahead - 2 * q + q_behind) / RATE_STEP_S**2
    return GaitMotion(q, qd, qdd, *feet_paths(gait, t, frame.ankle_z_m))


RATE_STEP_S = 1e-3


def _pose(gait: Gait, ch: Character, stand_qpos: np.ndarray, t: np.ndarray, frame: StandFrame) -> np.ndarray:
    """qpos (n, nq) of the keyed gait at times ``t``: the pelvis on its path, each leg's angles from IK with the
    foot flat, everything else as in the stand pose."""
    offset_x, height = frame.offset_x_m, frame.height_m
    ax_, az_ = feet_paths(gait, t, frame.ankle_z_m)[:2]
    px, pz = pelvis_path(gait, t, offset_x, height)
    pitch = float(stand_qpos[2])
    q = np.tile(stand_qpos, (t.size, 1))
    q[:, 0] += px - offset_x  # the stand pose's pelvis is ``offset_x`` ahead of its ankles, at x = 0
    q[:, 1] += pz - height
    names = ch.dof_names
    for f, side in enumerate("rl"):
        thigh, knee = leg_ik(ax_[:, f] - px, az_[:, f] - pz, frame.thigh_m, frame.shank_m)
        q[:, names.index(f"hip_{side}")] = thigh - pitch
        q[:, names.index(f"knee_{side}")] = knee
        q[:, names.index(f"ankle_{side}")] = -(thigh + knee)  # the foot flat: pitch + hip + knee + ankle = 0
    return q


def check_gait(gait: Gait, stand_qpos: np.ndarray, clip_s: float) -> None:
    """CmrtError, in one line, for a gait the legs cannot do or the clip cannot hold: a keyed frame out of a leg's
    reach or past a joint's range, or a clip ending before the body is back at rest (``SETTLE_S`` after the pose
    is back at standing)."""
    start, _ = gait.speed_up_s
    if start < -1e-9:
        raise CmrtError(f"gait: the body speeds up over two steps before the second mid-swing: gait_first_step_s "
                        f"must be at least {gait.first_step_s - start:g} s")
    if gait.end_s + SETTLE_S > clip_s:
        raise CmrtError(f"the gait ends at {gait.end_s:g} s: clip_s must be at least {gait.end_s + SETTLE_S:g} s "
                        "(the body comes to rest)")
    ch = character()
    t = np.arange(0.0, gait.end_s + CHECK_STEP_S, CHECK_STEP_S)
    frame = stand_frame(ch, stand_qpos)
    ax_, az_ = feet_paths(gait, t, frame.ankle_z_m)[:2]
    px, pz = pelvis_path(gait, t, frame.offset_x_m, frame.height_m)
    far = np.hypot(ax_ - px[:, None], az_ - pz[:, None]).max()
    if far > frame.reach_m + 1e-9:
        raise CmrtError(f"gait: a foot {far:.3f} m from the hip is out of the leg's reach ({frame.reach_m:.2f} m): "
                        "shorten gait_step_length_m or deepen gait_crouch_m")
    q = _pose(gait, ch, stand_qpos, t, frame)
    lo, hi = ch.joint_range_rad()
    dofs = list(ch.actuated_dofs)
    outside = (q[:, dofs] < lo - 1e-9) | (q[:, dofs] > hi + 1e-9)
    if outside.any():
        name = ch.dof_names[dofs[int(np.flatnonzero(outside.any(axis=0))[0])]]
        raise CmrtError(f"gait: {name} leaves its range: shorten gait_step_length_m or lower gait_lift_m")
