"""The planar body's motion on the 3D body, joint by joint by name (docs/body3d.md).

The 3D body's sagittal hinges are the planar body's - the same names, axes, signs, ranges and segments - so a
planar reference motion (``Task.reference``: the planar tasks' poses, eased) is the 3D body's with every other
joint (rolls, yaws) held at zero: a sagittal pose stands the 3D body exactly where it stands the planar one
(tested to 1e-9). The roots differ (planar x, z, pitch; a free joint): ``planar_to_3d`` leaves them out (the
controller tracks the actuated joints), ``planar_state_to_3d`` maps them too. Played so, the 3D body's CoM, linear
momentum and angular momentum are the planar body's (to 1e-14, a test; the lateral ones zero): the same motion
asks the same ground force and CoP of both - what lets ``cmrt check`` judge a 3D pose change on its planar twin.
"""

from __future__ import annotations

from functools import cache

import numpy as np

from cmrt.body.character import character

BODY = "humanoid3d"


@cache
def _pairs() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(planar qpos, planar dof, 3D qpos, 3D dof) addresses of every actuated planar joint."""
    planar, spatial = character().model, character(BODY).model
    rows = []
    for a in range(planar.nu):
        j = int(planar.actuator_trnid[a, 0])
        j3 = spatial.joint(planar.joint(j).name).id  # every planar joint is a 3D one (a test)
        rows.append((planar.jnt_qposadr[j], planar.jnt_dofadr[j], spatial.jnt_qposadr[j3], spatial.jnt_dofadr[j3]))
    return tuple(np.array(col, dtype=np.int64) for col in zip(*rows, strict=True))


def planar_to_3d(q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, base_qpos: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The planar reference (q, qd, qdd: (n, nv) of the planar body) as the 3D body's ((n, nq), (n, nv), (n, nv)):
    ``base_qpos`` (the 3D body's standing qpos: its root and the joints the planar body lacks) with the planar
    joints' angles, rates and accelerations put in."""
    pq, pv, sq, sv = _pairs()
    m = character(BODY).model
    n = len(q)
    q3 = np.repeat(np.asarray(base_qpos, float)[None, :], n, axis=0)
    qd3, qdd3 = np.zeros((n, m.nv)), np.zeros((n, m.nv))
    q3[:, sq], qd3[:, sv], qdd3[:, sv] = q[:, pq], qd[:, pv], qdd[:, pv]
    return q3, qd3, qdd3


def planar_state_to_3d(q: np.ndarray, qd: np.ndarray, base_qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One planar state (q, qd: (nv,) of the planar body) as the 3D body's (qpos (nq,), qvel (nv,)), its root
    included: the planar root's slides are offsets from the pelvis body's place, the free joint's position is
    absolute; a pitch about y is the quaternion (cos p/2, 0, sin p/2, 0)."""
    planar = character().model
    q3, qd3, _ = planar_to_3d(q[None, :], qd[None, :], np.zeros((1, planar.nv)), base_qpos)
    q3, qd3 = q3[0], qd3[0]
    home = planar.body("pelvis").pos
    x, z, pitch = q[0], q[1], q[2]
    q3[0:3] = (home[0] + x, 0.0, home[2] + z)
    q3[3:7] = (np.cos(pitch / 2.0), 0.0, np.sin(pitch / 2.0), 0.0)
    qd3[0:3] = (qd[0], 0.0, qd[1])  # the free joint's linear velocity (world) and angular velocity (its frame)
    qd3[3:6] = (0.0, qd[2], 0.0)
    return q3, qd3
