"""The stance a body stands in where its feet are: a pose's upper body and pelvis pitch over feet flat at given
places, the pelvis over the support so the CoM stands over the support's centre.

After a step the feet are no longer where the task's pose has them: standing there is not the pose itself (its
hips straight, a split stance cannot take it) but the pose stood over those feet. The stepping supervisor settles
into this stance (``cmrt.control.stepping``) and a stepping clip's final pose is judged against it
(``Task.final_pose_error_rad``), so "back to standing" means one thing for the controller and for the verdict.

Geometry (the MJCF, checked by tests/body/test_stance.py against MuJoCo's kinematics): the hip sits at the pelvis
body's origin, thigh and shank are 0.43 m each along the body's -z, the heel point is 6 cm behind and 6 cm below
the ankle, its sphere 1 cm in radius. The farther foot's leg keeps the pose's own hip-to-ankle distance (its knee
as in the pose); the pelvis comes down as far as that needs and the nearer leg bends more.
"""

from __future__ import annotations

import functools
import math

import mujoco
import numpy as np
from scipy.optimize import brentq

from cmrt.body.character import FOOT_POINT_RADIUS_M, character, support_interval_x
from cmrt.errors import CmrtError

THIGH_M = 0.43  # hip to knee
SHANK_M = 0.43  # knee to ankle (equal segments: the knee bisects the hip-ankle line's angle)
ANKLE_TO_HEEL_M = (-0.06, -0.06)  # heel point from the ankle, in the foot's frame (x forward, z up)
ANKLE_HEIGHT_M = FOOT_POINT_RADIUS_M - ANKLE_TO_HEEL_M[1]  # ankle above the floor, foot flat


@functools.cache
def _leg_dofs() -> tuple[tuple[int, int, int], tuple[int, int, int]]:
    """The qpos addresses of each leg's (hip, knee, ankle): ``Character.leg_dofs``'s joints."""
    ch = character()
    m = ch.model
    return tuple(tuple(int(m.jnt_qposadr[m.dof_jntid[dof]]) for dof in leg) for leg in ch.leg_dofs)


@functools.cache
def _pelvis_home_z() -> float:
    m = character().model
    return float(m.body("pelvis").pos[2])


def _set_legs(qpos: np.ndarray, pelvis_x: float, ankle_x: tuple[float, float], leg_length_m: float) -> None:
    """Legs of ``qpos`` reaching flat feet with ankles at ``ankle_x`` from a pelvis at ``pelvis_x`` (pitch as in
    ``qpos``), the pelvis as high as the farther ankle allows at ``leg_length_m`` hip to ankle."""
    far = max(abs(a - pelvis_x) for a in ankle_x)
    if far >= leg_length_m:
        raise CmrtError(f"feet {abs(ankle_x[0] - ankle_x[1]):.2f} m apart: too far for a stance")
    hip_z = ANKLE_HEIGHT_M + math.sqrt(leg_length_m ** 2 - far ** 2)
    qpos[0], qpos[1] = pelvis_x, hip_z - _pelvis_home_z()  # root_z slides from the MJCF's pelvis height
    pitch = qpos[2]
    for (hip, knee, ankle), a_x in zip(_leg_dofs(), ankle_x, strict=True):
        dx, dz = a_x - pelvis_x, hip_z - ANKLE_HEIGHT_M
        reach = math.hypot(dx, dz)
        bend = 2.0 * math.acos(min(reach / (THIGH_M + SHANK_M), 1.0))
        thigh = math.atan2(-dx, dz) - 0.5 * bend  # the thigh's angle from straight down (+: foot behind)
        qpos[hip], qpos[knee], qpos[ankle] = thigh - pitch, bend, -(thigh + bend)


def stance_qpos(pose_qpos: np.ndarray, heel_x_m: tuple[float, float]) -> np.ndarray:
    """``pose_qpos`` (a feet-flat pose) stood over feet whose heel points are at ``heel_x_m`` (right, left): its
    upper body and pelvis pitch, legs reaching those feet flat, the CoM over the support's centre. With the feet
    where the pose has them it is the pose itself."""
    m = character().model
    d = mujoco.MjData(m)
    knee = _leg_dofs()[0][1]
    leg_m = (THIGH_M + SHANK_M) * math.cos(0.5 * float(pose_qpos[knee]))
    ankle_x = tuple(float(h) - ANKLE_TO_HEEL_M[0] for h in heel_x_m)
    q = np.array(pose_qpos, float)

    def offset(pelvis_x: float) -> float:
        _set_legs(q, pelvis_x, ankle_x, leg_m)
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        lo, hi = support_interval_x(d)
        return float(d.subtree_com[0, 0] - 0.5 * (lo + hi))

    lo, hi = min(ankle_x) - 0.3, max(ankle_x) + 0.3
    lo, hi = max(lo, max(ankle_x) - 0.999 * leg_m), min(hi, min(ankle_x) + 0.999 * leg_m)
    if lo >= hi or offset(lo) * offset(hi) > 0:
        raise CmrtError(f"feet {abs(ankle_x[0] - ankle_x[1]):.2f} m apart: no stance over them")
    offset(brentq(offset, lo, hi, xtol=1e-12))
    return q


def feet_heel_x(qpos: np.ndarray) -> tuple[float, float]:
    """Where a qpos puts the right and left heel points (x, m)."""
    ch = character()
    d = mujoco.MjData(ch.model)
    d.qpos[:] = qpos
    mujoco.mj_kinematics(ch.model, d)
    return tuple(float(d.geom_xpos[pair[0], 0]) for pair in ch.foot_points)


def leg_offsets(pose_qpos: np.ndarray, heel_r_x_m: float, heel_l_x_m: float) -> np.ndarray:
    """The right and left leg's (hip, knee, ankle) angles of the stance over these heels less the pose's (rad):
    what the stepping supervisor adds to the reference after a step. Zero where no stance reaches the feet."""
    legs = [dof for leg in _leg_dofs() for dof in leg]
    try:
        stance = stance_qpos(pose_qpos, (heel_r_x_m, heel_l_x_m))
    except CmrtError:
        return np.zeros(6)
    return stance[legs] - np.asarray(pose_qpos, float)[legs]
