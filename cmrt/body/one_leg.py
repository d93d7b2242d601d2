"""The 3D body's weight shift onto one foot and its one-leg stance, as poses: what a leg lift's reference moves
through (docs/body3d.md).

Standing on the left foot, a person brings the pelvis over that foot before the right one leaves the floor. Here
the pelvis stays level and moves sideways by the legs' roll: the stance hip adducts by ``roll`` and the other
abducts by as much, each ankle turning back by ``roll`` (a parallelogram: both feet stay flat where they stood);
``roll`` is solved so that the CoM of the lifted pose is over the stance foot's centre. The other leg then lifts
its foot by flexing hip and knee, its ankle keeping the sole about level. Every pose keeps the stance foot's body
exactly where it stood (the root is moved to put it there).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.optimize import brentq

from cmrt.body.character import character

BODY = "humanoid3d"
SIDES = ("r", "l")


@dataclass(frozen=True)
class OneLegPoses:
    """Standing, shifted over the stance foot (both feet down) and lifted (the other foot up), as qpos."""

    standing: np.ndarray
    shifted: np.ndarray
    lifted: np.ndarray
    stance: int  # 0 right, 1 left
    roll_rad: float  # the stance leg's adduction (and its ankle's eversion)
    stance_centre_xy_m: np.ndarray  # the stance foot's contact points' centre


def _qadr(name: str) -> int:
    m = character(BODY).model
    return int(m.jnt_qposadr[m.joint(name).id])


def _placed(q: np.ndarray, stance: int, where: np.ndarray) -> np.ndarray:
    """``q`` with its root moved so that the stance foot's body is at ``where``."""
    ch = character(BODY)
    d = mujoco.MjData(ch.model)
    d.qpos[:] = q
    mujoco.mj_kinematics(ch.model, d)
    out = q.copy()
    out[:3] += where - d.xpos[ch.foot_bodies[stance]]
    return out


def _com(q: np.ndarray) -> np.ndarray:
    m = character(BODY).model
    d = mujoco.MjData(m)
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    mujoco.mj_comPos(m, d)
    return d.subtree_com[1].copy()


def one_leg_poses(standing: np.ndarray, stance: int = 1, hip_flex_rad: float = 0.5, knee_flex_rad: float = 1.0
                  ) -> OneLegPoses:
    """The shift and lift poses from a feet-flat ``standing`` qpos of the 3D body (``stance``: the foot kept)."""
    ch = character(BODY)
    d = mujoco.MjData(ch.model)
    d.qpos[:] = standing
    mujoco.mj_kinematics(ch.model, d)
    foot_at = d.xpos[ch.foot_bodies[stance]].copy()
    pair = ch.foot_points[stance]
    centre = d.geom_xpos[list(pair), :2].mean(axis=0)
    s, o = SIDES[stance], SIDES[1 - stance]
    sign = 1.0 if stance == 1 else -1.0  # the roll axes are mirrored: one sign means adduction on both sides

    def pose(roll: float, lift: float) -> np.ndarray:
        q = standing.copy()
        q[_qadr(f"hip_roll_{s}")] -= roll  # adduction is negative roll on both sides (mirrored axes)
        q[_qadr(f"ankle_roll_{s}")] += roll
        q[_qadr(f"hip_roll_{o}")] += roll  # the other leg abducts as much: a parallelogram, its foot stays put
        q[_qadr(f"ankle_roll_{o}")] -= roll
        q[_qadr(f"hip_{o}")] -= lift * hip_flex_rad
        q[_qadr(f"knee_{o}")] += lift * knee_flex_rad
        q[_qadr(f"ankle_{o}")] -= lift * (knee_flex_rad - hip_flex_rad)
        return _placed(q, stance, foot_at)

    roll = brentq(lambda r: sign * (_com(pose(r, 1.0))[1] - centre[1]), 0.0, 0.4, xtol=1e-10)
    return OneLegPoses(standing.copy(), pose(roll, 0.0), pose(roll, 1.0), stance, float(roll), centre)
