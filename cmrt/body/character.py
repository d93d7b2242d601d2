"""The humanoids (``BODIES``: the planar one, the default, and the 3D one): model loading, names and indices,
and feet-flat poses.

Everything that knows the MJCF's names lives here, so the controller and the
simulator work with integer indices only.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
from scipy.optimize import brentq

from cmrt.errors import CmrtError

MODEL_PATH = Path(__file__).parent / "humanoid.xml"
MODEL3D_PATH = Path(__file__).parent / "humanoid3d.xml"
#: Rows of the spatial momentum [L_x, L_y, L_z, H_x, H_y, H_z] (and of a frame's [linear, angular] velocity) a body
#: moves in: the sagittal plane's L_x, L_z, H_y, or all six. The controller's arithmetic is written once in 6D
#: (``cmrt.control.kernel.centroidal_spatial``); a planar body is its rows.
PLANAR_ROWS = (0, 2, 4)
SPATIAL_ROWS = (0, 1, 2, 3, 4, 5)
#: The bodies a task may name: (MJCF, momentum rows). ``planar`` is the default and the paper's.
BODIES = {"planar": (MODEL_PATH, PLANAR_ROWS), "humanoid3d": (MODEL3D_PATH, SPATIAL_ROWS)}

#: Joints a task pose may name; a bare name ("hip") sets both sides.
POSE_JOINTS = ("lumbar", "neck", "shoulder", "elbow", "hip", "knee", "ankle")
SIDED_JOINTS = ("shoulder", "elbow", "hip", "knee", "ankle")
FOOT_POINT_RADIUS_M = 0.01
STANCE_HEEL_X_M = -0.06  # where a standing pose puts the right heel point (feet_flat_qpos): the feet's settled place
#: Gravity (m/s^2, pointing down), the MJCF's ``<option gravity>`` (tests/body/test_character.py checks they
#: agree): the one value the controller, the fall monitor, the props and the objective use. numba compiles it
#: into its cached functions (sim/balance.py), so it is a constant, never changed at run time.
GRAVITY_M_S2 = 9.81


@functools.cache
def load_model(path: str = str(MODEL_PATH)) -> mujoco.MjModel:
    """Compile the MJCF once per process (compiling costs ~10 ms; models are read-only)."""
    return mujoco.MjModel.from_xml_path(path)


@dataclass(frozen=True)
class Character:
    """Indices into the model that the controller and simulator need."""

    model: mujoco.MjModel
    mass_kg: float
    root_dofs: tuple[int, int, int]  # slide x, slide z, hinge pitch
    actuated_dofs: tuple[int, ...]  # dof of each actuator, actuator order
    torque_limit_nm: np.ndarray  # per actuator
    foot_bodies: tuple[int, int]  # right, left
    foot_points: tuple[tuple[int, int], tuple[int, int]]  # (heel, toe) geom per foot
    floor_geom: int
    thorax_body: int
    dof_names: tuple[str, ...]
    body: str = "planar"  # a key of ``BODIES``
    momentum_rows: tuple[int, ...] = PLANAR_ROWS  # of the spatial momentum (``PLANAR_ROWS``, ``SPATIAL_ROWS``)

    @property
    def nv(self) -> int:
        """Degrees of freedom of the humanoid (root x, z, pitch and the joints)."""
        return self.model.nv

    @property
    def ankle_dofs(self) -> tuple[int, int]:
        """The right and left ankle's dof (a tilted support turns them: ``cmrt.body.surface``)."""
        return tuple(int(self.model.joint(n).dofadr[0]) for n in ("ankle_r", "ankle_l"))

    @property
    def foot_point_geoms(self) -> tuple[int, ...]:
        """Geom ids of the feet's contact spheres, right foot's first (planar: right heel, right toe, left heel,
        left toe; 3D: each foot's heel_in, heel_out, toe_in, toe_out)."""
        return tuple(g for pair in self.foot_points for g in pair)

    def joint_range_rad(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) of each actuator's joint (rad; +-inf for an unlimited joint): the stops of the MJCF."""
        m = self.model
        joints = m.actuator_trnid[:, 0]
        limited = m.jnt_limited[joints].astype(bool)
        return (np.where(limited, m.jnt_range[joints, 0], -np.inf), np.where(limited, m.jnt_range[joints, 1], np.inf))

    @property
    def leg_dofs(self) -> tuple[tuple[int, int, int], tuple[int, int, int]]:
        """The dofs of each leg's sagittal chain, (hip, knee, ankle), right leg first: the same joints on every
        body (the 3D body's roll and yaw hinges are others)."""
        return tuple(tuple(self.dof(f"{j}_{s}") for j in ("hip", "knee", "ankle")) for s in ("r", "l"))

    def dof(self, joint_name: str) -> int:
        """The dof index of a joint by name."""
        return int(self.model.joint(joint_name).dofadr[0])


def character(body: str = "planar") -> Character:
    """A body's names and indices, built once per process from its MJCF (``BODIES``): the same path for every body.

    The root's dofs are the pelvis's joints (planar: slide x, slide z, pitch; 3D: a free joint's six), a foot's
    contact points its contact spheres in MJCF order."""
    if body not in BODIES:
        raise CmrtError(f"unknown body {body!r} (known: {', '.join(BODIES)})")
    return _character(body)


@functools.cache
def _character(body: str) -> Character:
    path, rows = BODIES[body]
    m = load_model(str(path))
    name = lambda obj, i: mujoco.mj_id2name(m, obj, i)  # noqa: E731
    dof_names = tuple(name(mujoco.mjtObj.mjOBJ_JOINT, int(m.dof_jntid[i])) for i in range(m.nv))
    gid = lambda n: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, n)  # noqa: E731
    bid = lambda n: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n)  # noqa: E731
    feet = (bid("foot_r"), bid("foot_l"))
    return Character(
        model=m,
        mass_kg=float(m.body_subtreemass[0]),
        root_dofs=tuple(j for j in range(m.nv) if m.dof_bodyid[j] == bid("pelvis")),
        actuated_dofs=tuple(int(m.jnt_dofadr[m.actuator_trnid[a, 0]]) for a in range(m.nu)),
        torque_limit_nm=m.actuator_ctrlrange[:, 1].copy(),
        foot_bodies=feet,
        foot_points=tuple(tuple(g for g in range(m.ngeom) if m.geom_bodyid[g] == foot and m.geom_contype[g])
                          for foot in feet),
        floor_geom=gid("floor"),
        thorax_body=bid("thorax"),
        dof_names=dof_names,
        body=body,
        momentum_rows=rows,
    )


def joint_angles_from_pose(pose_rad: dict[str, float], body: str = "planar") -> dict[str, float]:
    """Expand a pose (bare names set both sides: ``hip``, and on the 3D body ``hip_roll``...) into per-joint
    angles; unknown names fail."""
    ch = character(body)
    out = {n: 0.0 for j, n in enumerate(ch.dof_names) if j not in ch.root_dofs}
    for key, value in pose_rad.items():
        if f"{key}_r" in out and f"{key}_l" in out:
            out[f"{key}_r"] = out[f"{key}_l"] = float(value)
        elif key in out:
            out[key] = float(value)
        else:
            known = POSE_JOINTS if body == "planar" else sorted({n[:-2] if n[-2:] in ("_r", "_l") else n for n in out})
            raise CmrtError(f"unknown joint '{key}' in pose (known: {', '.join(known)} or *_r/*_l)")
    return out


def _root_pose(ch: Character, qpos: np.ndarray, x_m: float, z_m: float, pitch_rad: float) -> None:
    """Put the root at (x, z) pitched by ``pitch_rad`` about y, in place: the planar body's slides and hinge, or
    the 3D body's free joint (position, unit quaternion)."""
    if len(ch.root_dofs) == 3:
        qpos[0], qpos[1], qpos[2] = x_m, z_m, pitch_rad
    else:
        qpos[0], qpos[2] = x_m, z_m
        qpos[3:7] = (np.cos(0.5 * pitch_rad), 0.0, np.sin(0.5 * pitch_rad), 0.0)


def support_interval_x(data: mujoco.MjData, foot: int | None = None, body: str = "planar") -> tuple[float, float]:
    """[heel x, toe x] over both feet (or one): the support interval of flat feet."""
    ch = character(body)
    feet = ch.foot_points if foot is None else (ch.foot_points[foot],)
    xs = [data.geom_xpos[g, 0] for pair in feet for g in pair]
    return float(min(xs)), float(max(xs))


def feet_flat_qpos(angles_rad: dict[str, float], balance_joint: str | None = "ankle", body: str = "planar"
                   ) -> np.ndarray:
    """qpos for a pose with both feet flat on the floor, right heel point at x = -0.06 m.

    Root pitch follows from the right leg (foot pitch = root + hip + knee + ankle = 0; a pose's out-of-plane
    joints are the 3D body's own business: its feet are flat if they leave the soles level).
    If ``balance_joint`` is given (both sides of it), its angle is solved so that the
    CoM lies over the centre of the support interval: a statically balanced pose.
    """
    ch = character(body)
    m = ch.model
    d = mujoco.MjData(m)
    angles = dict(angles_rad)
    for side in ("hip", "knee", "ankle"):
        if abs(angles[f"{side}_r"] - angles[f"{side}_l"]) > 1e-12:
            raise CmrtError("both feet are on the ground: left and right leg angles must match")

    def place(ankle_offset: float) -> float:
        a = dict(angles)
        if balance_joint:
            a[f"{balance_joint}_r"] = a[f"{balance_joint}_l"] = angles[f"{balance_joint}_r"] + ankle_offset
        d.qpos[:] = 0.0
        for jname, val in a.items():
            d.qpos[m.joint(jname).qposadr[0]] = val
        pitch = -(a["hip_r"] + a["knee_r"] + a["ankle_r"])
        _root_pose(ch, d.qpos, 0.0, 0.0, pitch)
        mujoco.mj_kinematics(m, d)
        heel = d.geom_xpos[ch.foot_points[0][0]]
        _root_pose(ch, d.qpos, STANCE_HEEL_X_M - heel[0], FOOT_POINT_RADIUS_M - heel[2], pitch)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        lo, hi = support_interval_x(d, body=body)
        return float(d.subtree_com[0, 0] - 0.5 * (lo + hi))

    if balance_joint:
        if place(-0.6) * place(0.6) > 0:
            raise CmrtError(f"cannot balance the pose with the {balance_joint} joint alone")
        offset = brentq(place, -0.6, 0.6, xtol=1e-12)
        place(offset)
    else:
        place(0.0)
    _check_joint_ranges(m, d.qpos)
    return d.qpos.copy()


def _check_joint_ranges(m: mujoco.MjModel, qpos: np.ndarray) -> None:
    """CmrtError naming the first joint of a pose outside its range in the MJCF (the balance joint's solved angle
    included): a pose the body cannot take is bad input, not a motion to simulate."""
    for j in range(m.njnt):
        if m.jnt_limited[j]:
            lo, hi = m.jnt_range[j]
            angle = qpos[m.jnt_qposadr[j]]
            if not lo - 1e-9 <= angle <= hi + 1e-9:
                raise CmrtError(f"{m.joint(j).name} = {np.degrees(angle):.1f} deg is outside the joint's range "
                                f"[{np.degrees(lo):.1f}, {np.degrees(hi):.1f}] deg")
