"""The ground the character stands on: a still level floor, a slope, a plane that tilts or moves, and its friction.

A support that tilts or moves is simulated *in its own frame* (ABC section 3 writes the CMRT relative to the base
of support for that reason): MuJoCo's floor stays the plane z = 0 of that frame, and every body feels what the
frame's motion adds to gravity. With the frame's origin O(t) (the pivot, under the feet's centre) and its tilt
theta(t) about +y (support coordinates x = R(theta)^T (X - O)), a body of mass m at x moving at v feels

    m [R^T (g - O'') + omega^2 x - alpha (z, -x) - 2 omega (v_z, -v_x)]   and a torque  -I_yy alpha

(gravity and the frame's acceleration, centrifugal, Euler and Coriolis terms; omega = theta', alpha = theta'').
For a rigid frame this is exact, not a model: the same motion as on a platform driven through that trajectory
(tests/body/test_surface.py checks a sliding block against a real driven MuJoCo platform). MuJoCo keeps its own
gravity (0, 0, -g); ``Support.field`` is the rest, applied as ``xfrc_applied`` at each body's CoM every physics
step and handed to the controller as a known load. Contact, the CoP, falls, "standing still" and foot slip are
then all measured relative to the support, as they should be.

Parameters (task ``[params]``, so ``--set`` reaches them; all zero/one: the still level floor of before, and the
content hashes of such tasks do not change):

* ``floor_friction``: the floor's sliding friction (MuJoCo takes the floor's, by its geom priority); the
  controller plans with ``ControllerConfig.friction_coef`` times it;
* ``slope_deg``: a static incline, positive rising ahead of the character (+x uphill);
* ``tilt_amplitude_deg``, ``tilt_period_s``: a plane tilting about the pivot, theta = A sin(2 pi t / T),
  rising ahead first (Yu's shaking plane swings between -20 and +20 degrees);
* ``sway_amplitude_m``, ``sway_period_s``; ``heave_amplitude_m``, ``heave_period_s``: the platform translating
  horizontally / vertically, A sin(2 pi t / T).

Each oscillation fades in over its first period and out over the last period of the clip (``_oscillation``): a
platform starts from rest, and the standing tail after the clip is on a support at rest (at its slope), so that a
success still ends standing still.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from cmrt.body.character import GRAVITY_M_S2

#: The surface parameters every task has, with the defaults of the still level floor.
SURFACE_PARAMS: dict[str, float] = {
    "floor_friction": 1.0,
    "slope_deg": 0.0,
    "tilt_amplitude_deg": 0.0,
    "tilt_period_s": 2.0,
    "sway_amplitude_m": 0.0,
    "sway_period_s": 1.0,
    "heave_amplitude_m": 0.0,
    "heave_period_s": 1.0,
    "box_mass_kg": 0.0,  # > 0: the character stands on a box floating on water (cmrt.body.floating_box)
    "box_stiffness_n_m": 9810.0,  # the water's buoyancy stiffness: rho g x 1 m^2 of waterline
    "box_damping_ratio": 0.3,
}
#: The floating box's parameters (the others are the prescribed support's).
BOX_PARAMS = ("box_mass_kg", "box_stiffness_n_m", "box_damping_ratio")
#: The one that changes the compiled model (the others act through ``Support.field``).
MODEL_PARAMS = ("floor_friction",)
FLOOR_PRIORITY = 1  # above the feet's and props' 0: the contact takes the floor's friction, not the larger of two
PAD_GEOM = "heel_r"  # a foot point: its solref is the heel pad's
# The contact model on any support but the still level floor of default friction (the floor of before keeps its
# model, bit for bit: its tangential loads are brief). Measured on stand with a 100 N push, 4 s:
# * MuJoCo's soft friction lets a contact creep under a lasting tangential load (the constraint is a damper on the
#   contact's velocity: a steady force needs a steady slip): on a 15 degree slope a planted foot crept 4.8 cm in 4 s;
# * its default pyramidal cone with the no-slip pass stops that creep, but at Yu's friction 0.08 it unloaded
#   sliding feet for a step and hit the floor at 2.3 body weights;
# * the elliptic cone slides them smoothly (peak 1.01 body weights), and a frictional impedance IMPRATIO times the
#   normal one holds a planted foot (0.2 mm in 4 s on the slope, against 2.4 mm at 10); the no-slip pass then
#   changes nothing measurable, so it is off. (Controller v0.6, the heel pad: docs/surfaces.md.)
CONE = mujoco.mjtCone.mjCONE_ELLIPTIC
IMPRATIO = 100.0

@dataclass(frozen=True)
class Support:
    """The support surface of a task (``from_params``); angles in radians inside, degrees in the parameters."""

    floor_friction: float = 1.0
    slope_deg: float = 0.0
    tilt_amplitude_deg: float = 0.0
    tilt_period_s: float = 2.0
    sway_amplitude_m: float = 0.0
    sway_period_s: float = 1.0
    heave_amplitude_m: float = 0.0
    heave_period_s: float = 1.0
    box_mass_kg: float = 0.0
    box_stiffness_n_m: float = 9810.0
    box_damping_ratio: float = 0.3
    moving_until_s: float = math.inf  # the motions fade out before this (the clip's end: the tail stands still)

    @classmethod
    def from_params(cls, params: dict[str, float]) -> Support:
        return cls(**{k: float(params.get(k, v)) for k, v in SURFACE_PARAMS.items()},
                   moving_until_s=float(params.get("clip_s", math.inf)))

    @property
    def still_and_level(self) -> bool:
        """No field at all: the floor of before (friction aside)."""
        return (self.slope_deg == 0.0 and self.tilt_amplitude_deg == 0.0 and self.sway_amplitude_m == 0.0
                and self.heave_amplitude_m == 0.0 and not self.floating)

    @property
    def floating(self) -> bool:
        """On a floating box: the support's motion is the box's (``cmrt.body.floating_box``), not ``tilt``/``origin``
        (which then describe a still level floor)."""
        return self.box_mass_kg > 0.0

    @property
    def kind(self) -> str:
        """A one-word name for tables: level, slippery, slope, shaking, swaying, heaving (or a mix: '+')."""
        kinds = [k for k, on in (("slope", self.slope_deg != 0.0), ("shaking", self.tilt_amplitude_deg != 0.0),
                                 ("swaying", self.sway_amplitude_m != 0.0), ("heaving", self.heave_amplitude_m != 0.0),
                                 ("floating", self.floating))
                 if on]
        if self.floor_friction != 1.0:
            kinds.append("slippery" if self.floor_friction < 1.0 else "rough")
        return "+".join(kinds) or "level"

    # --- the frame's motion (theta about +y: positive takes the floor's +x end down) ---------------------------
    def tilt(self, t_s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """theta (rad), omega (rad/s), alpha (rad/s^2) at times ``t_s``."""
        theta, omega, alpha = _oscillation(t_s, -math.radians(self.tilt_amplitude_deg), self.tilt_period_s,
                                           self.moving_until_s)
        return theta - math.radians(self.slope_deg), omega, alpha  # rising ahead: theta < 0

    def origin(self, t_s) -> tuple[np.ndarray, np.ndarray]:
        """The pivot's world position (x, z) and acceleration (x, z) at times ``t_s``, each (..., 2)."""
        sway = _oscillation(t_s, self.sway_amplitude_m, self.sway_period_s, self.moving_until_s)
        heave = _oscillation(t_s, self.heave_amplitude_m, self.heave_period_s, self.moving_until_s)
        return np.stack([sway[0], heave[0]], axis=-1), np.stack([sway[2], heave[2]], axis=-1)

    def uniform_field(self, t_s) -> np.ndarray:
        """R^T (g - O''): gravity and the frame's own acceleration in support coordinates (x, z), m/s^2 - what
        the character must lean into (the rotation's terms depend on where a body is)."""
        theta, _, _ = self.tilt(t_s)
        _, acc = self.origin(t_s)
        gx, gz = -acc[..., 0], -GRAVITY_M_S2 - acc[..., 1]
        c, s = np.cos(theta), np.sin(theta)
        return np.stack([c * gx - s * gz, s * gx + c * gz], axis=-1)

    def field(self, t_s: float, pos: np.ndarray, vel: np.ndarray, mass_kg: np.ndarray,
              inertia_yy: np.ndarray) -> np.ndarray:
        """(n, nb, 3): force x, z (N) at each body's CoM and torque about y (N m) that the support's tilt and
        motion add to MuJoCo's gravity, for bodies at ``pos`` moving at ``vel`` ((n, nb, 2) x, z in support
        coordinates); ``mass_kg``, ``inertia_yy`` (nb,) (the world body's zero mass gives it nothing)."""
        _, omega, alpha = (float(v) for v in self.tilt(t_s))
        u = self.uniform_field(t_s)
        return frame_field(omega, alpha, u[0], u[1], pos, vel, mass_kg, inertia_yy)

    def lean_x(self, t_s, com_z_m):
        """Where the CoM stands over a CoP at 0 under gravity in support coordinates: x = z g_x / g_z = -z tan
        theta (the ground's force along gravity's line through the CoM). A body upright in the world is there.
        The platform's own acceleration is left out: it changes too fast for a CoM to follow (a 5 cm sway at
        1 Hz would swing this target by 20 cm), and the balance feedback answers it. 0 on a level floor."""
        return lean_x(self.tilt(t_s)[0], com_z_m)

    def lean_rate(self, t_s: float, com_z_m, com_vel_z_m_s):
        """d/dt of ``lean_x`` (m/s): a body upright in the world moves over a tilting support at this speed."""
        theta, omega, _ = (float(v) for v in self.tilt(t_s))
        return -com_z_m * omega / math.cos(theta) ** 2 - com_vel_z_m_s * math.tan(theta)

    def lean_accel(self, t_s: float, com_z_m):
        """d^2/dt^2 of ``lean_x`` at a constant CoM height (m/s^2): the feedforward that lets the CoM follow the
        lean of a shaking plane (PD feedback alone lags a 0.5 Hz, +-0.35 m lean by ~27 degrees, ~0.18 m)."""
        theta, omega, alpha = (float(v) for v in self.tilt(t_s))
        sec2 = 1.0 / math.cos(theta) ** 2
        return -com_z_m * (alpha * sec2 + 2.0 * omega * omega * math.tan(theta) * sec2)

    def pose(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """The support frame's world pose at ``t_s``: rotation (3, 3; a turn of theta about +y) and origin (3,),
        world = rotation @ support + origin. For pictures."""
        o = self.origin(t_s)[0]
        return pose_matrix(float(self.tilt(t_s)[0]), float(o[0]), float(o[1]))



def frame_field(omega, alpha, ux, uz, pos: np.ndarray, vel: np.ndarray, mass_kg: np.ndarray,
                inertia_yy: np.ndarray) -> np.ndarray:
    """``Support.field`` for a frame turning at ``omega`` (rad/s), ``alpha`` (rad/s^2) whose gravity less its
    acceleration is (``ux``, ``uz``) in its own axes (m/s^2): scalars, or (n, 1) per simulation of a batch
    (a floating box: each simulation's box moves its own way)."""
    x, z = pos[..., 0], pos[..., 1]
    vx, vz = vel[..., 0], vel[..., 1]
    ax = (ux + omega * omega * x - alpha * z - 2.0 * omega * vz)
    az = (uz + GRAVITY_M_S2) + omega * omega * z + alpha * x + 2.0 * omega * vx
    out = np.empty(pos.shape[:-1] + (3,))
    out[..., 0] = mass_kg * ax
    out[..., 1] = mass_kg * az
    out[..., 2] = -inertia_yy * alpha
    return out


def uniform_field(theta, origin_acc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R^T (g - O''), support axes (``Support.uniform_field``), for per-simulation tilts ``theta`` (n,) and
    origin accelerations (n, 2)."""
    gx, gz = -origin_acc[..., 0], -GRAVITY_M_S2 - origin_acc[..., 1]
    c, s = np.cos(theta), np.sin(theta)
    return c * gx - s * gz, s * gx + c * gz


def lean_x(theta, com_z_m):
    """``Support.lean_x`` for per-simulation tilts."""
    return -com_z_m * np.tan(theta)


def lean_rate(theta, omega, com_z_m, com_vel_z_m_s):
    """``Support.lean_rate`` for per-simulation tilts and turning rates."""
    return -com_z_m * omega / np.cos(theta) ** 2 - com_vel_z_m_s * np.tan(theta)


def pose_matrix(theta: float, x_m: float, z_m: float) -> tuple[np.ndarray, np.ndarray]:
    """A support frame's world pose (``Support.pose``) from its tilt and its origin's world x, z."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]), np.array([x_m, 0.0, z_m])


def _ramp(u: np.ndarray, scale_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The quintic smoothstep of ``u`` = t / scale (0 before, 1 after; zero rate and acceleration at both ends)
    and its first two time derivatives."""
    v = np.clip(u, 0.0, 1.0)
    inside = (u > 0.0) & (u < 1.0)
    e = v ** 3 * (10.0 - 15.0 * v + 6.0 * v * v)
    de = np.where(inside, 30.0 * v * v * (1.0 - v) ** 2 / scale_s, 0.0)
    dde = np.where(inside, 60.0 * v * (1.0 - v) * (1.0 - 2.0 * v) / scale_s ** 2, 0.0)
    return e, de, dde


def _oscillation(t_s, amplitude: float, period_s: float, until_s: float = math.inf):
    """A sin(2 pi t / T), faded in over its first period and out over the period before ``until_s`` (a platform
    starts from rest - without the fade it would start turning at full speed, an infinite acceleration - and is at
    rest again for the standing tail, so "standing still" keeps its meaning), and its first two derivatives."""
    t = np.asarray(t_s, dtype=float)
    if amplitude == 0.0 or not math.isfinite(period_s):
        zero = np.zeros_like(t)
        return zero, zero, zero
    w = 2.0 * math.pi / period_s
    e1, de1, dde1 = _ramp(t / period_s, period_s)
    if math.isfinite(until_s):
        e2, de2, dde2 = _ramp((until_s - t) / period_s, period_s)
        de2, dde2 = -de2, dde2  # d/dt of a function of (until - t)
    else:
        e2, de2, dde2 = np.ones_like(t), np.zeros_like(t), np.zeros_like(t)
    e, de, dde = e1 * e2, de1 * e2 + e1 * de2, dde1 * e2 + 2.0 * de1 * de2 + e1 * dde2
    s, c = np.sin(w * t), np.cos(w * t)
    return (amplitude * e * s, amplitude * (de * s + e * w * c),
            amplitude * (dde * s + 2.0 * de * w * c - e * w * w * s))


def add_to_spec(spec: mujoco.MjSpec, values: dict[str, float]) -> None:
    """The floor's friction and the contact model of a surface (only when a task sets one: the default model is
    the one of before, bit for bit)."""
    if "floor_friction" in values:
        floor = spec.geom("floor")
        floor.friction[0] = values["floor_friction"]
        floor.priority = FLOOR_PRIORITY
        # priority hands the floor every parameter of its contacts, solref too: without this the feet lost their heel
        # pad (humanoid.xml) on any floor of another friction. The floor carries the pad's contact instead: the
        # average MuJoCo takes of the two geoms' solref without priority (solmix 1 each)
        floor.solref = 0.5 * (np.asarray(floor.solref) + np.asarray(spec.geom(PAD_GEOM).solref))
    if values.get("surface"):
        spec.option.cone = CONE
        spec.option.impratio = IMPRATIO


def model_values(params: dict[str, float]) -> tuple[tuple[str, float], ...]:
    """The surface's part of the model key: the friction when it is not the default's, and the contact model of
    any surface but the still level floor of default friction."""
    changed = tuple((k, float(params[k])) for k in MODEL_PARAMS if k in params and params[k] != SURFACE_PARAMS[k])
    other = any(params.get(k, v) != v for k, v in SURFACE_PARAMS.items())
    return changed + ((("surface", 1.0),) if other else ())


def body_inertia_yy(model: mujoco.MjModel, data: mujoco.MjData | None = None) -> np.ndarray:
    """Each body's moment of inertia about its CoM's y axis (kg m^2): every body turns about y only, so this is
    the planar one (from its principal inertia and the inertial frame's orientation)."""
    if data is None:
        data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, data)
    rot = data.ximat.reshape(-1, 3, 3)
    return np.einsum("bk,bk->b", rot[:, 1, :] ** 2, model.body_inertia)


def tilt_pose(model: mujoco.MjModel, qpos: np.ndarray, theta_rad: float) -> np.ndarray:
    """``qpos`` (the humanoid's) stood upright on a support tilted by ``theta_rad``: everything above the ankles
    turned by -theta about them (the body stays vertical in the world, the feet flat on the support), the root
    moved so that the feet stay where they were."""
    q = np.array(qpos, dtype=float)
    if theta_rad == 0.0:
        return q
    d = mujoco.MjData(model)
    d.qpos[: q.size] = q
    mujoco.mj_kinematics(model, d)
    foot = model.body("foot_r").id
    before = d.xpos[foot].copy()
    for name in ("ankle_r", "ankle_l"):
        q[model.joint(name).qposadr[0]] += theta_rad
    q[2] -= theta_rad
    d.qpos[: q.size] = q
    mujoco.mj_kinematics(model, d)
    q[0] += before[0] - d.xpos[foot][0]
    q[1] += before[2] - d.xpos[foot][2]
    return q
