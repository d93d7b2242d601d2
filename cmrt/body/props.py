"""Task props added to the character's model: a thrown ball, a free slab, a punching pad.

A task file names its prop in ``[prop] kind = "..."``; the prop's numbers live in the
task's ``[params]`` (so ``--set ball_mass_kg=1`` works) and the model is rebuilt (and
cached per process) for each distinct set of them. Props are appended after the
humanoid with ``MjSpec``, so every humanoid body, joint, dof, geom and sensor keeps its
index and the controller works on the leading slices of the batch arrays.

* ``ball``: a sphere on planar joints, held still until it is released on a ballistic arc
  (gravity on) that brings it to the hands at ``ball_arrival_s`` with speed
  ``ball_speed_m_s``, descending at ``ball_angle_deg``, after ``ball_flight_s`` of flight.
  When it touches a hand (the last ``HAND_LENGTH_M`` of a forearm) a ``connect`` equality to each
  forearm is switched on (the grip, made at contact) and the ball stops colliding. Caught = gripped
  and held: the hands within ``max_ball_sag_m`` of where the reference holds them, from the grip on,
  for the last ``ball_hold_s``. From the grip on, the controller plans with the ball's measured pull
  on the hands (``Ball.hand_load``: -m (a - g) of the ball, an external force on the forearms in the
  QP), and the balance monitor counts the ball's mass in the CoM it judges (``Prop.held_mass``; a
  held ball pulls, it does not hold the body up as a slab leant on does: ``holds_body_up``). With
  ``ball_balanced`` 1, once the grip has brought the ball to the hands' velocity (at most
  ``ball_grip_settle_s`` later), its mass is moved into the two forearms (per-simulation model
  fields, ``mj_setConst``): from then on MuJoCo's own dynamics of the character - the
  momentum matrix, the mass matrix, gravity - carry the load, and so does the controller
  (it balances body and ball together). The ball body keeps ``BALL_RESIDUAL_MASS_KG``. With 0 the ball
  stays a load on the hands to the end: felt (ABC's reactive controller), and counterweighted in part if
  ``ball_counterweight`` > 0: a reaction time after the grip the controller moves its CoM target back so that its
  body and that share of the ball stand over it together (``Prop.held_mass``'s share).
* ``slab``: a free block (planar joints: it can slide and tip) standing on the floor in
  front of the character; floor friction 1.0 (MuJoCo takes the larger of the two geoms').
  Toppled when it has rotated past its balance angle and is falling (``TOPPLED_DEG``), by a push: first
  touched inside the task window and never struck harder than ``max_push_force_n`` (``MAX_PUSH_FORCE_N``).
  The controller plans with the slab's measured push-back on the hands (``Slab.hand_load``: contact
  sensors, normal and friction), as with a held ball: the tracked arms hold against the slab instead of
  folding under it, and the plan's CoP carries the push's reaction.
* ``wall``: a fixed pad (a punching target); its contact stiffness is ``wall_timeconst_s``.

Each kind is one class (``Ball``, ``Slab``, ``Pad``) behind the interface of ``Prop`` (the
base: no prop), registered in ``PROPS`` by its ``kind``: its parameter defaults
(``PARAMS``), those that change the compiled model (``MODEL_PARAMS``), how it adds itself
to the humanoid's ``MjSpec`` (``add_to_spec``) and its per-clip behaviour in the batched
simulation loop (an instance per clip batch).

Contact with a prop is measured every physics step: touch sensors around the forearms
(hands included) for the slab and the pad, and for the ball the force the hands apply to
it, m (a - g), from its acceleration.
"""

from __future__ import annotations

import functools
import math
from typing import ClassVar

import mujoco
import numpy as np

from cmrt.body import surface
from cmrt.body.character import BODIES, GRAVITY_M_S2
from cmrt.errors import CmrtError
from cmrt.inputs import Range

BALL_RADIUS_M = 0.12
FOREARM_RADIUS_M = 0.035
HAND_OFFSET_M = np.array([0.0, 0.0, -0.40])  # forearm frame -> fingertip end of the capsule
HAND_LENGTH_M = 0.19  # the hand: the last 0.108 H (Winter) of the forearm+hand capsule, where a ball is gripped
WRIST_OFFSET_M = HAND_OFFSET_M + np.array([0.0, 0.0, HAND_LENGTH_M])  # forearm frame -> the wrist
GRIP_TOLERANCE_M = 0.005  # the ball counts as touching a hand within this gap
GRIP_TIMECONST_S = 0.01  # the grip's constraint time constant (MuJoCo's default 0.02 lets 12 kg wobble)
GRIP_SETTLE_S = 0.06  # at the latest this long after the grip the load is handed to the forearms
#: ``ball_counterweight`` (with ``ball_balanced`` 0): the controller starts to counterweight the ball it holds this
#: long after the grip - the balance feedback's 0.1 s delay and 0.1 s to respond (compensatory postural responses to
#: a load begin ~0.1-0.2 s after it) - and takes COUNTERWEIGHT_RAMP_S to move its CoM target (a smoothstep: slow
#: against the feedback delay, so the CoM follows by the ankles and the hips barely move). docs/controller.md, *Catch*.
COUNTERWEIGHT_REACTION_S = 0.2
COUNTERWEIGHT_RAMP_S = 0.5
BALL_HOLD_S = 0.3  # a catch is held when the hands have stayed this long within max_ball_sag_m of the reference
GRIP_SETTLED_M_S = 0.05  # ... or as soon as the ball moves with the point it is held at to within this
BALL_RESIDUAL_MASS_KG = 0.05  # what the ball body keeps once its mass is in the forearms
CONTACT_FORCE_N = 1.0  # a hand-prop force above this counts as contact
MAX_PUSH_FORCE_N = 1000.0  # a push, not a strike: the hands' peak force on a slab (1.5 body weights)
TOPPLED_DEG = 30.0  # a slab rotated this far has passed its balance angle and is falling
SLAB_WIDTH_M = 0.6
SLAB_PUSH_DATA = 2 | 16  # a contact sensor's data: force (3) and position (3), in the world frame
SLAB_PUSH_REDUCE = 3  # ... summed over the contacts it matches (MuJoCo's reduce="netforce")
BAG_LENGTH_M = 1.0  # a 100 cm heavy bag
BAG_THICKNESS_M = 0.35  # 35 cm across
BAG_DAMPING_RATIO = 0.05  # of critical: a bag swings several times before it hangs still


def _free_planar(body, prefix: str) -> None:
    for name, jtype, axis in ((f"{prefix}_x", mujoco.mjtJoint.mjJNT_SLIDE, [1, 0, 0]),
                              (f"{prefix}_z", mujoco.mjtJoint.mjJNT_SLIDE, [0, 0, 1]),
                              (f"{prefix}_pitch", mujoco.mjtJoint.mjJNT_HINGE, [0, 1, 0])):
        j = body.add_joint(name=name, type=jtype, axis=axis)
        j.limited = mujoco.mjtLimited.mjLIMITED_FALSE
        j.armature = 0.0


def spatial_spec(spec: mujoco.MjSpec) -> bool:
    """Whether the humanoid in ``spec`` is the 3D body (a free root): a prop on it moves in space."""
    return any(j.type == mujoco.mjtJoint.mjJNT_FREE for j in spec.joints)


def ball_release(p: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """(x, z) position and velocity at release that bring the ball to the catch point on time."""
    angle = math.radians(p["ball_angle_deg"])
    v_arrive = p["ball_speed_m_s"] * np.array([-math.cos(angle), -math.sin(angle)])
    gravity = np.array([0.0, -GRAVITY_M_S2])
    tau = p["ball_flight_s"]
    v0 = v_arrive - gravity * tau
    p0 = np.array([p["ball_reach_m"], p["ball_height_m"]]) - v0 * tau - 0.5 * gravity * tau**2
    return p0, v0


def _hand_touch_sensors(spec: mujoco.MjSpec) -> None:
    """Touch sensors around each forearm (hand included): the normal force of what the arms touch. They
    come after the humanoid's four foot sensors; before any fall the arms touch only the prop."""
    for side in ("r", "l"):
        body = spec.body(f"forearm_{side}")
        body.add_site(name=f"hand_touch_{side}", type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                      size=[FOREARM_RADIUS_M + 0.01, 0.2, 0], pos=[0, 0, -0.2], rgba=[0, 0, 0, 0])
        spec.add_sensor(name=f"hand_touch_{side}", type=mujoco.mjtSensor.mjSENS_TOUCH,
                        objtype=mujoco.mjtObj.mjOBJ_SITE, objname=f"hand_touch_{side}")


def fist_velocity(b: dict, rows: np.ndarray, hands: np.ndarray, root: int) -> np.ndarray:
    """(rows, hands, 2) x/z velocity (m/s) of the fist points (``HAND_OFFSET_M`` in each forearm's frame) of
    simulations ``rows``, from the batch's ``cvel`` (rotation, then the translation of the point at the subtree
    CoM of ``root``, the body the hands' chain hangs from) - what ``mj_objectVelocity`` gives at the fist."""
    R = b["xmat"][rows][:, hands].reshape(rows.size, hands.size, 3, 3)
    fist = b["xpos"][rows][:, hands] + R @ HAND_OFFSET_M
    cvel = b["cvel"][rows][:, hands]
    v = cvel[..., 3:] + np.cross(cvel[..., :3], fist - b["subtree_com"][rows, root][:, None])
    return v[..., [0, 2]]


def fist_reach(b: dict, rows: np.ndarray, hands: np.ndarray, shoulders: np.ndarray, arm_m: float) -> np.ndarray:
    """(rows, hands) how far each fist point is from its shoulder in the sagittal plane, as a fraction of the arm's
    length ``arm_m`` (1: the arm straight): how extended the arm is, whatever the elbow and shoulder angles."""
    R = b["xmat"][rows][:, hands].reshape(rows.size, hands.size, 3, 3)
    reach = (b["xpos"][rows][:, hands] + R @ HAND_OFFSET_M - b["xpos"][rows][:, shoulders])[..., [0, 2]]
    return np.hypot(reach[..., 0], reach[..., 1]) / arm_m


def fingertip_z(model: mujoco.MjModel, qpos: np.ndarray) -> float:
    """Height of the right fingertip in pose ``qpos`` (the humanoid's coordinates)."""
    d = mujoco.MjData(model)
    d.qpos[: qpos.size] = qpos
    mujoco.mj_kinematics(model, d)
    hand = model.body("forearm_r").id
    return float((d.xpos[hand] + d.xmat[hand].reshape(3, 3) @ HAND_OFFSET_M)[2])


class Prop:
    """Per-clip behaviour of a prop inside the batched simulation loop (this base: no prop).

    A subclass declares its ``kind`` (the task file's ``[prop] kind``), its task parameters with
    defaults (``PARAMS``), those of them that change the compiled model (``MODEL_PARAMS``), and adds
    itself to the humanoid's ``MjSpec`` in ``add_to_spec``; an instance runs one batch of clips."""

    kind: ClassVar[str | None] = None
    #: task parameters the prop reads when the model is built or the clip runs, with defaults
    PARAMS: ClassVar[dict[str, float]] = {}
    #: the parameters that change the compiled model (the others only change how a clip runs)
    MODEL_PARAMS: ClassVar[tuple[str, ...]] = ()
    #: the allowed range of each parameter (checked when a task is loaded or ``--set``): a mass, size or time
    #: constant is positive, so MuJoCo never compiles a degenerate body
    LIMITS: ClassVar[dict[str, Range]] = {}
    #: the body whose mass an ensemble member may scale (None: the prop has no mass that matters)
    mass_body: ClassVar[str | None] = None
    #: the prop acts every physics step (a ball released or caught at the right instant), not every control step
    every_step: ClassVar[bool] = False
    #: the hands can lean on the prop (a slab): while they touch it the body is held up, and the inverted pendulum's
    #: capture point does not apply. A held ball only pulls on the hands.
    holds_body_up: ClassVar[bool] = True
    #: the prop is struck (a bag, a pad): it stops the striking limb, whose motion is judged on time up to the
    #: first contact (objective.timing_lag_s) - what follows is the target's physics, not the motion asked for
    struck: ClassVar[bool] = False

    @classmethod
    def check(cls, p: dict[str, float]) -> None:
        """CmrtError if the task's parameters ``p`` are ones the prop cannot use (beyond their ranges, ``LIMITS``)."""

    @classmethod
    def add_to_spec(cls, spec: mujoco.MjSpec, p: dict[str, float]) -> None:
        """Add the prop's bodies, geoms, joints, equalities and sensors to the humanoid's ``spec`` (after
        the humanoid's own, so their indices stay), built from its model parameters ``p``."""

    def __init__(self, model: mujoco.MjModel, params: dict[str, float]):
        self.model, self.params = model, params
        self.sensors = None  # sensordata indices of the hands' touch sensors, if the prop has them
        if any(model.sensor(i).name == "hand_touch_r" for i in range(model.nsensor)):
            self.sensors = [model.sensor(f"hand_touch_{side}").adr[0] for side in ("r", "l")]
        self.carried_kg = np.zeros(0)  # per simulation: prop mass the character carries (kg; sized by start())

    def fields(self) -> set[str]:
        """Batch fields the prop reads or writes besides the simulator's own."""
        return set()

    def settle_hold(self, b: dict) -> None:
        """Keep the prop still while the character settles."""

    def start(self, batch, b: dict, n: int, end_qpos: np.ndarray, mass_scale: np.ndarray | None = None) -> None:
        """Set up the clip's start (``end_qpos``: the task's target pose; ``mass_scale`` (n,): each
        simulation's prop mass as a multiple of the task's)."""
        self.carried_kg = np.zeros(n)
        if self.mass_body is not None and mass_scale is not None and np.any(mass_scale != 1.0):
            body = self.model.body(self.mass_body).id
            mass, inertia = batch.expand("body_mass"), batch.expand("body_inertia")
            mass[:, body] *= mass_scale
            inertia[:, body] *= mass_scale[:, None]
            batch.set_const()  # derived quantities (subtree masses) follow the new masses

    def step(self, batch, b: dict, ids: np.ndarray, t: float) -> None:
        """Called before a step at time ``t`` for the active simulations."""

    def extras(self, b: dict, rows: np.ndarray) -> dict[str, np.ndarray]:
        """Figures of the prop for simulations ``rows`` now (e.g. how far a held ball sagged)."""
        return {}

    def hand_load(self, b: dict, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """A load the character holds and the controller plans with, for simulations ``rows``: its force on
        the hands (n, 2) x/z N, where it acts (n, 3) and the bodies sharing it; None: none."""
        return None

    def held_mass(self, b: dict, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """Mass the hands hold that the character's own bodies do not carry yet, for simulations ``rows``: kg (n,),
        its (x, z) (n, 2) and x velocity (n,) - part of what balances and falls (the balance monitor adds it to the
        character's CoM) - and the share of it (n,) the controller balances now (its CoM target moved so that body
        and held mass stand over the target together). None: none."""
        return None

    def contact_force(self, b: dict, sel) -> np.ndarray | None:
        """Force between the character's hands and the prop during the step just taken (N), or None."""
        if self.sensors is None:
            return None
        data = b["sensordata"][sel]
        return data[:, self.sensors[0]] + data[:, self.sensors[1]]

    def success(self, b: dict, rows: np.ndarray, contact_force_n: np.ndarray, times: np.ndarray,
                window: tuple[float, float]) -> np.ndarray | None:
        """For simulations ``rows``, now (at the end of the run, or at a fall): was the goal reached?
        None for pure pose changes. ``contact_force_n`` (rows, steps) is the history so far."""
        return None


class Ball(Prop):
    """A ball tossed on a ballistic arc to the hands, gripped at contact, its mass then carried by the forearms."""

    kind = "ball"
    PARAMS = {"ball_mass_kg": 7.0, "ball_speed_m_s": 4.0, "ball_angle_deg": 10.0, "ball_flight_s": 0.4,
              "ball_arrival_s": 1.35, "ball_height_m": 1.36, "ball_reach_m": 0.86, "max_ball_sag_m": 0.1,
              "ball_hold_s": BALL_HOLD_S, "ball_grip_timeconst_s": GRIP_TIMECONST_S,
              "ball_grip_settle_s": GRIP_SETTLE_S, "ball_balanced": 1.0, "ball_counterweight": 0.0,
              "ball_radius_m": BALL_RADIUS_M}
    MODEL_PARAMS = ("ball_mass_kg", "ball_grip_timeconst_s", "ball_radius_m")
    LIMITS = {"ball_mass_kg": Range(0.1, 100.0, unit="kg"),  # above BALL_RESIDUAL_MASS_KG: the hand-over moves it
              "ball_radius_m": Range(0.02, 0.5, unit="m"),
              "ball_speed_m_s": Range(0.0, 50.0, unit="m/s"), "ball_angle_deg": Range(-90.0, 90.0, unit="deg"),
              "ball_flight_s": Range(0.01, 10.0, unit="s"), "ball_arrival_s": Range(0.0, 60.0, unit="s"),
              "ball_height_m": Range(0.0, 5.0, unit="m"), "ball_reach_m": Range(-5.0, 5.0, unit="m"),
              "max_ball_sag_m": Range(0.0, 2.0, unit="m"), "ball_hold_s": Range(0.0, 10.0, unit="s"),
              # the grip's constraint time constant: >= 2 physics steps (MuJoCo's stability rule), at most 0.5 s
              "ball_grip_timeconst_s": Range(0.004, 0.5, unit="s"),
              "ball_grip_settle_s": Range(0.004, 2.0, unit="s"),
              # 1: once the grip has settled the controller balances body and ball together (the ball's mass moves
              # into the forearms); 0: never - the ball stays a load on the hands, felt (its pull is in the plan) but
              # not balanced: ABC's reactive controller, to which the ball is a disturbance
              "ball_balanced": Range(0.0, 1.0),  # 0 or 1 (``check``)
              # with ball_balanced 0: the share of the held ball's moment the controller counterweights, its CoM
              # target moved back so that the body and that share of the ball stand over it together, from
              # COUNTERWEIGHT_REACTION_S after the grip (0: none - the ball only felt)
              "ball_counterweight": Range(0.0, 1.0)}
    mass_body = "ball"
    every_step = True
    holds_body_up = False

    @classmethod
    def check(cls, p):
        if p.get("ball_balanced", 1.0) not in (0.0, 1.0):
            raise CmrtError(f"ball_balanced must be 0 or 1, got {p['ball_balanced']:g}")
        if p.get("ball_balanced", 1.0) and p.get("ball_counterweight", 0.0):
            raise CmrtError("ball_counterweight needs ball_balanced = 0 (with 1 the controller balances all the ball)")

    @classmethod
    def add_to_spec(cls, spec, p):
        body = spec.worldbody.add_body(name="ball", pos=[0, 0, 0])
        if spatial_spec(spec):  # on the 3D body a ball, free in space (its hands may squeeze it, not the world)
            body.add_freejoint(name="ball")
        else:
            _free_planar(body, "ball")
        radius = p.get("ball_radius_m", BALL_RADIUS_M)
        body.add_geom(name="ball", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[radius, 0, 0], mass=p["ball_mass_kg"],
                      contype=1, conaffinity=1, rgba=[0.8, 0.3, 0.1, 1])
        for side in ("r", "l"):  # both hands grip: the load is shared by the two arms
            eq = spec.add_equality(name=f"catch_{side}", type=mujoco.mjtEq.mjEQ_CONNECT, name1=f"forearm_{side}",
                                   name2="ball", objtype=mujoco.mjtObj.mjOBJ_BODY, active=False)
            eq.solref = [p.get("ball_grip_timeconst_s", GRIP_TIMECONST_S), 1.0]

    def __init__(self, model, params):
        super().__init__(model, params)
        self.body = model.body("ball").id
        self.geom = model.geom("ball").id
        self.spatial = model.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE
        adr = model.joint("ball" if self.spatial else "ball_x")
        n_q, n_v = (7, 6) if self.spatial else (3, 3)
        self.dofs = slice(adr.dofadr[0], adr.dofadr[0] + n_v)
        self.qpos = slice(adr.qposadr[0], adr.qposadr[0] + n_q)
        self.xz = [0, 2] if self.spatial else [0, 1]  # x, z within both
        # the ball's x and z in its qpos and qvel: planar joints (x, z, pitch), or a free joint on the 3D body
        # (position, quaternion; linear, angular velocity)
        self.forearms = (model.body("forearm_r").id, model.body("forearm_l").id)
        self.release_pos, self.release_vel = ball_release(params)
        self.release_s = params["ball_arrival_s"] - params["ball_flight_s"]
        self.radius_m = params.get("ball_radius_m", BALL_RADIUS_M)
        # the grip's gap: on the 3D body the hands are where they are, and the ball is gripped where its surface
        # meets a hand's in space; the planar body's arms swing in planes either side of the ball's, so there it is
        # gripped where they meet in the sagittal plane
        # per-clip state, set by start() for the clip's n simulations
        self.reference_tip_z = math.nan  # height of the right fingertip in the task's end pose (m)
        self.released = np.zeros(0, bool)  # the ball has left the thrower's hand
        self.grip_s = np.zeros(0)  # when the hands gripped it (s; NaN: not yet)
        self.handed_over = np.zeros(0, bool)  # its mass has moved into the forearms
        self.handover_s = np.zeros(0)  # when (s; NaN: not yet)
        self.drift = np.zeros((0, 2))  # the ball's (x, z) offset from its anchor on the right forearm, last step
        self.held_sag_m = np.zeros(0)  # largest |sag| of the hands since the grip (m; NaN: not gripped)
        self._now_s = 0.0  # the time of the last step (s)
        self.out_s = np.zeros(0)  # the last time the hands were off the reference by more than max_ball_sag_m (s)
        # ... and the batch's per-simulation model fields the ball changes (views: batch.expand)
        self.eq_data = np.zeros(0)
        self.gravcomp = np.zeros(0)
        self.mass = np.zeros(0)
        self.inertia = np.zeros(0)
        self.ipos = np.zeros(0)
        self.iquat = np.zeros(0)
        self.contype = np.zeros(0)
        self.conaffinity = np.zeros(0)

    def fields(self):
        return {"xmat", "eq_active", "qacc"}

    def _hold(self, b: dict, rows) -> None:
        x, z = self.release_pos
        b["qpos"][rows, self.qpos] = [x, 0.0, z, 1.0, 0.0, 0.0, 0.0] if self.spatial else [x, z, 0.0]
        b["qvel"][rows, self.dofs] = 0.0

    def settle_hold(self, b):
        self._hold(b, slice(None))

    def start(self, batch, b, n, end_qpos, mass_scale=None):
        super().start(batch, b, n, end_qpos, mass_scale)
        self.reference_tip_z = fingertip_z(self.model, end_qpos)
        self.eq_data = batch.expand("eq_data")
        self.gravcomp = batch.expand("body_gravcomp")
        self.mass = batch.expand("body_mass")
        self.inertia = batch.expand("body_inertia")
        self.ipos = batch.expand("body_ipos")
        self.iquat = batch.expand("body_iquat")
        self.contype = batch.expand("geom_contype")
        self.conaffinity = batch.expand("geom_conaffinity")
        self.gravcomp[:, self.body] = 1.0  # held in the thrower's hand until the release
        self._hold(b, slice(None))
        self.released = np.zeros(n, bool)
        self.grip_s = np.full(n, np.nan)
        self.handed_over = np.zeros(n, bool)
        self.drift = np.zeros((n, 2))
        self.handover_s = np.full(n, np.nan)
        self.held_sag_m = np.full(n, np.nan)
        self.out_s = np.full(n, np.inf)  # not held yet

    def step(self, batch, b, ids, t):
        self._now_s = t
        held = ids[~np.isnan(self.grip_s[ids])]
        if held.size:  # the hold, from the grip on: the hands must stay where the reference holds them, up or down
            sag = np.abs(self.reference_tip_z - self._tip_z(b, held))
            self.held_sag_m[held] = np.fmax(self.held_sag_m[held], sag)
            off = (sag > self.params["max_ball_sag_m"]) | np.isinf(self.out_s[held])
            self.out_s[held[off]] = t
        release = ids[~self.released[ids]]
        if release.size and t >= self.release_s - 1e-9:
            vx, vz = self.release_vel
            b["qvel"][release, self.dofs] = [vx, 0.0, vz, 0.0, 0.0, 0.0] if self.spatial else [vx, vz, 0.0]
            self.gravcomp[release, self.body] = 0.0
            self.released[release] = True
        elif release.size:
            self._hold(b, release)
        free = ids[self.released[ids] & np.isnan(self.grip_s[ids])]
        if free.size:
            gap = self._hand_gap(b, free)
            for sim in free[gap <= GRIP_TOLERANCE_M]:  # the grip, made at contact
                for eq, body in enumerate(self.forearms):
                    Rb = b["xmat"][sim, body].reshape(3, 3)
                    self.eq_data[sim, eq, 0:3] = Rb.T @ (b["xpos"][sim, self.body] - b["xpos"][sim, body])
                    self.eq_data[sim, eq, 3:6] = 0.0  # the ball's centre
                    b["eq_active"][sim, eq] = 1.0
                # held: the grip alone carries it (its compliance lets the ball sink into the hands, which a contact
                # with the forearm it overlaps would fight)
                self.contype[sim, self.geom] = self.conaffinity[sim, self.geom] = 0
                self.grip_s[sim] = t
        if not self.params.get("ball_balanced", 1.0):
            return  # the ball stays a load on the hands
        held = ids[~self.handed_over[ids] & ~np.isnan(self.grip_s[ids])]
        due = held[self._settled(b, held, t)]
        if due.size:
            for sim in due:
                self._hand_over(b, sim)
            self.handover_s[due] = t
            anchors = self.eq_data.copy()  # mj_setConst recomputes connect anchors from qpos0: keep ours
            batch.set_const()
            self.eq_data[:] = anchors

    def _hand_gap(self, b: dict, rows: np.ndarray) -> np.ndarray:
        """Gap (m) between the ball's surface and the right hand's (the last ``HAND_LENGTH_M`` of the forearm
        capsule, to the fingertip), in the sagittal plane (in space on the 3D body): < 0 where they overlap."""
        hand = self.forearms[0]
        axes = [0, 1, 2] if self.spatial else [0, 2]
        R = b["xmat"][rows, hand].reshape(-1, 3, 3)
        tip = (b["xpos"][rows, hand] + R @ HAND_OFFSET_M)[:, axes]
        wrist = (b["xpos"][rows, hand] + R @ WRIST_OFFSET_M)[:, axes]
        ball = b["xpos"][rows, self.body][:, axes]
        axis = tip - wrist
        s = np.clip(np.einsum("ij,ij->i", ball - wrist, axis) / np.einsum("ij,ij->i", axis, axis), 0.0, 1.0)
        nearest = wrist + s[:, None] * axis
        gap = ball - nearest
        distance = np.linalg.norm(gap, axis=1) if self.spatial else np.hypot(*gap.T)
        return distance - self.radius_m - FOREARM_RADIUS_M

    def _settled(self, b: dict, rows: np.ndarray, t: float) -> np.ndarray:
        """Has the grip brought the ball to the hands' motion? The drift of the ball away from its anchor
        on the right forearm, step to step, is their relative velocity."""
        if rows.size == 0:
            return np.zeros(0, bool)
        body = self.forearms[0]
        R = b["xmat"][rows, body].reshape(-1, 3, 3)
        anchor = b["xpos"][rows, body] + (R @ self.eq_data[rows, 0, 0:3, None])[..., 0]
        drift = (b["xpos"][rows, self.body] - anchor)[:, [0, 2]]
        dt = self.model.opt.timestep
        rate = np.hypot(*(drift - self.drift[rows]).T) / dt
        self.drift[rows] = drift
        fresh = t - self.grip_s[rows] < 2 * dt  # no previous drift yet
        settle_s = self.params.get("ball_grip_settle_s", GRIP_SETTLE_S)
        return ~fresh & ((rate < GRIP_SETTLED_M_S) | (t - self.grip_s[rows] >= settle_s - 1e-9))

    def _hand_over(self, b: dict, sim: int) -> None:
        """Move the ball's mass into the forearms (half each, at the ball's place in their frames)."""
        m_ball = self.mass[sim, self.body] - BALL_RESIDUAL_MASS_KG
        half = 0.5 * m_ball
        own = 0.4 * half * self.radius_m**2  # a solid sphere's inertia about its centre
        for body in self.forearms:
            R = b["xmat"][sim, body].reshape(3, 3)
            r = R.T @ (b["xpos"][sim, self.body] - b["xpos"][sim, body])  # ball centre, forearm frame
            m_f, c_f = self.mass[sim, body], self.ipos[sim, body].copy()
            q = self.iquat[sim, body]
            Rf = np.empty(9)
            mujoco.mju_quat2Mat(Rf, q)
            Rf = Rf.reshape(3, 3)
            total = m_f + half
            c = (m_f * c_f + half * r) / total
            inertia = Rf @ np.diag(self.inertia[sim, body]) @ Rf.T + own * np.eye(3)
            for mass, point in ((m_f, c_f), (half, r)):
                d = point - c
                inertia += mass * (d @ d * np.eye(3) - np.outer(d, d))
            values, vectors = np.linalg.eigh(inertia)
            if np.linalg.det(vectors) < 0:
                vectors[:, 0] = -vectors[:, 0]
            quat = np.empty(4)
            mujoco.mju_mat2Quat(quat, vectors.ravel())
            self.mass[sim, body], self.ipos[sim, body] = total, c
            self.inertia[sim, body], self.iquat[sim, body] = values, quat
        self.mass[sim, self.body] = BALL_RESIDUAL_MASS_KG
        self.inertia[sim, self.body] = 0.4 * BALL_RESIDUAL_MASS_KG * self.radius_m**2
        self.contype[sim, self.geom] = self.conaffinity[sim, self.geom] = 0
        self.carried_kg[sim] = m_ball
        self.handed_over[sim] = True

    def hand_load(self, b, rows):
        """The held ball's pull on the hands, (force (n, 2) x/z N - (n, 3) x/y/z on the 3D body, point (n, 3), the
        forearms): -m (a - g) of the ball over the last step while it is gripped, zero otherwise."""
        f = np.zeros((rows.size, 3 if self.spatial else 2))
        held = ~np.isnan(self.grip_s[rows])
        if held.any():
            r = rows[held]
            acc = b["qacc"][r, self.dofs]
            m = self.mass[r, self.body]
            f[held, 0] = -m * acc[:, 0]
            if self.spatial:
                f[held, 1] = -m * acc[:, 1]
            f[held, -1] = -m * (acc[:, self.xz[1]] + GRAVITY_M_S2)
        return f, np.ascontiguousarray(b["xpos"][rows, self.body]), np.array(self.forearms, np.int64)

    def held_mass(self, b, rows):
        """The gripped ball until its mass is handed over to the forearms (from then on the forearms carry it), and
        how much of it the controller counterweights now (``ball_counterweight``)."""
        gripped = ~np.isnan(self.grip_s[rows]) & ~self.handed_over[rows]
        mass = np.where(gripped, self.mass[rows, self.body], 0.0)
        return mass, b["xpos"][rows, self.body][:, [0, 2]], b["qvel"][rows, self.dofs.start], self._balanced(rows)

    def _balanced(self, rows: np.ndarray) -> np.ndarray:
        """(n,) in [0, ``ball_counterweight``]: the share of the held ball the controller counterweights at the last
        step's time - a smoothstep over ``COUNTERWEIGHT_RAMP_S`` from ``COUNTERWEIGHT_REACTION_S`` after the grip."""
        share = self.params.get("ball_counterweight", 0.0)
        if share <= 0.0 or self.params.get("ball_balanced", 1.0):
            return np.zeros(rows.size)
        u = np.clip((self._now_s - self.grip_s[rows] - COUNTERWEIGHT_REACTION_S) / COUNTERWEIGHT_RAMP_S, 0.0, 1.0)
        return np.where(np.isnan(u), 0.0, share * (u * u * (3.0 - 2.0 * u)))

    def contact_force(self, b, sel):
        """|m (a - g)| of the ball: what the hands (or anything else) apply to it."""
        acc = b["qacc"][sel, self.dofs]
        mass = self.mass[sel, self.body]
        if self.spatial:
            return mass * np.sqrt(acc[:, 0] ** 2 + acc[:, 1] ** 2 + (acc[:, 2] + GRAVITY_M_S2) ** 2)
        return mass * np.hypot(acc[:, 0], acc[:, 1] + GRAVITY_M_S2)

    def success(self, b, rows, contact_force_n, times, window):
        """Caught, and held: the hands have stayed within ``max_ball_sag_m`` of where the reference holds them
        (above or below) for the last ``ball_hold_s``. Arms that give under the impact and bring the ball
        back are a catch; arms still down, or flung up over the head, at the end are not."""
        held_s = self.extras(b, rows)["ball_held_s"]
        return ~np.isnan(self.grip_s[rows]) & (held_s >= self.params["ball_hold_s"] - 1e-9)

    def _tip_z(self, b: dict, rows: np.ndarray) -> np.ndarray:
        hand = self.forearms[0]
        R = b["xmat"][rows, hand].reshape(-1, 3, 3)
        return (b["xpos"][rows, hand] + R @ HAND_OFFSET_M)[:, 2]

    def extras(self, b, rows):
        grip = self.grip_s[rows]
        sag = self.reference_tip_z - self._tip_z(b, rows)  # > 0: below the reference
        worst = np.fmax(self.held_sag_m[rows], np.abs(sag))
        held_s = np.maximum(self._now_s - self.out_s[rows], 0.0)
        caught = ~np.isnan(grip)
        return {"grip_s": grip, "handover_s": self.handover_s[rows],
                "ball_sag_m": np.where(caught, sag, np.nan),  # at the end (signed)
                "ball_max_sag_m": np.where(caught, worst, np.nan),  # the largest |sag| since the grip
                "ball_held_s": np.where(caught, held_s, 0.0)}  # how long the hands have been within the bound


class Slab(Prop):
    """A free-standing slab on the floor in front of the character, to be pushed over."""

    kind = "slab"
    PARAMS = {"slab_mass_kg": 140.0, "slab_x_m": 0.62, "slab_thickness_m": 0.25, "slab_height_m": 1.8,
              "max_push_force_n": MAX_PUSH_FORCE_N, "slab_timeconst_s": 0.01}
    MODEL_PARAMS = ("slab_mass_kg", "slab_x_m", "slab_thickness_m", "slab_height_m", "slab_timeconst_s")
    LIMITS = {"slab_mass_kg": Range(1.0, 10_000.0, unit="kg"), "slab_x_m": Range(0.2, 5.0, unit="m"),
              "slab_thickness_m": Range(0.01, 2.0, unit="m"), "slab_height_m": Range(0.05, 5.0, unit="m"),
              "max_push_force_n": Range(0.0, 1e6, unit="N"),
              "slab_timeconst_s": Range(0.004, 1.0, unit="s")}  # at least 2 x the 2 ms physics step
    mass_body = "slab"

    @classmethod
    def add_to_spec(cls, spec, p):
        t, h = p["slab_thickness_m"], p["slab_height_m"]
        body = spec.worldbody.add_body(name="slab", pos=[p["slab_x_m"] + t / 2, 0, h / 2 + 0.001])
        _free_planar(body, "slab")
        body.add_geom(name="slab", type=mujoco.mjtGeom.mjGEOM_BOX, size=[t / 2, SLAB_WIDTH_M / 2, h / 2],
                      mass=p["slab_mass_kg"], contype=1, conaffinity=1, friction=[1.0, 0.005, 0.0001],
                      solref=[p["slab_timeconst_s"], 1.0], rgba=[0.5, 0.5, 0.6, 1])
        _hand_touch_sensors(spec)
        for side in ("r", "l"):  # the full force (normal and friction) each forearm puts on the slab, and where
            sensor = spec.add_sensor(name=f"slab_push_{side}", type=mujoco.mjtSensor.mjSENS_CONTACT,
                                     objtype=mujoco.mjtObj.mjOBJ_BODY, objname=f"forearm_{side}",
                                     reftype=mujoco.mjtObj.mjOBJ_GEOM, refname="slab")
            sensor.intprm = [SLAB_PUSH_DATA, SLAB_PUSH_REDUCE, 1]

    def __init__(self, model, params):
        super().__init__(model, params)
        self.pitch = model.joint("slab_pitch").qposadr[0]
        self.push = [model.sensor(f"slab_push_{side}").adr[0] for side in ("r", "l")]
        self.forearms = (model.body("forearm_r").id, model.body("forearm_l").id)

    def fields(self):
        return {"xpos"}

    def hand_load(self, b, rows):
        """The slab's push back on the hands, (force (n, 2) x/z N, point (n, 3), the forearms): minus what the
        forearms put on it over the last physics step (MuJoCo's contact sensors: normal and friction), acting
        where they touch it. The controller plans with it as with a held ball: the arms hold their pose against
        the slab instead of folding under it, and the plan's CoP carries the push's reaction."""
        data = b["sensordata"][rows]
        r, left = (data[:, a: a + 6] for a in self.push)
        force = r[:, :3] + left[:, :3]
        weight = np.abs(r[:, 0]) + np.abs(left[:, 0])
        point = np.ascontiguousarray(b["xpos"][rows, self.forearms[0]])
        touching = weight > 0.0
        if touching.any():
            w_r = np.abs(r[touching, 0]) / weight[touching]
            point[touching] = w_r[:, None] * r[touching, 3:6] + (1.0 - w_r[:, None]) * left[touching, 3:6]
        return np.ascontiguousarray(-force[:, [0, 2]]), point, np.array(self.forearms, np.int64)

    def success(self, b, rows, contact_force_n, times, window):
        """Toppled (rotated away past its balance angle) by a push: the hands did not touch the slab before the
        task window - leaning on it from the preparation on is not a push (the optimizer finds that lean
        whenever the hands start within reach of it) - and never struck it harder than ``max_push_force_n``
        (a blow that knocks it over is a strike, not the push asked for)."""
        force = np.nan_to_num(contact_force_n)
        touching = force > CONTACT_FORCE_N
        early = (touching & (times < window[0] - 1e-9)).any(axis=1)
        struck = force.max(axis=1, initial=0.0) > self.params["max_push_force_n"]
        return (b["qpos"][rows, self.pitch] > math.radians(TOPPLED_DEG)) & ~early & ~struck


class Pad(Prop):
    """A fixed punching pad (kind ``wall``), to be struck and let go."""

    kind = "wall"
    struck = True
    PARAMS = {"wall_x_m": 0.58, "wall_timeconst_s": 0.01, "strike_impulse_n_s": 3.0, "max_contact_s": 0.3}
    MODEL_PARAMS = ("wall_x_m", "wall_timeconst_s")
    LIMITS = {"wall_x_m": Range(0.2, 5.0, unit="m"), "wall_timeconst_s": Range(0.001, 1.0, unit="s"),
              "strike_impulse_n_s": Range(0.0, 1e4, unit="N s"), "max_contact_s": Range(0.0, 60.0, unit="s")}

    @classmethod
    def add_to_spec(cls, spec, p):
        # in a body of its own (fixed, no joints): geoms of the world body itself would be
        # numbered before the humanoid's and shift their indices
        body = spec.worldbody.add_body(name="wall", pos=[p["wall_x_m"] + 0.05, 0, 1.3])
        body.add_geom(name="wall", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.05, 0.4, 0.4], contype=1,
                      conaffinity=1, solref=[p["wall_timeconst_s"], 1.0], rgba=[0.3, 0.3, 0.8, 1])
        _hand_touch_sensors(spec)

    def success(self, b, rows, contact_force_n, times, window):
        """A strike: enough impulse delivered inside the task window, no contact before it, and no
        contact lasting longer than ``max_contact_s`` (no leaning on the pad)."""
        return strike_success(contact_force_n, times, window, self.params["strike_impulse_n_s"],
                              self.params["max_contact_s"])


class Bag(Prop):
    """A heavy bag hanging as a pendulum in front of the character (kind ``bag``), to be struck and let go.

    A box of ``bag_mass_kg`` (``BAG_LENGTH_M`` long, ``BAG_THICKNESS_M`` deep: a 35 cm bag seen from the
    side), its centre ``bag_center_z_m`` up, hinged about +y at a pivot ``bag_rope_m`` above that centre
    (the chains, taken as rigid), its face at ``bag_x_m``. The swing is lightly damped (``BAG_DAMPING_RATIO``
    of critical). Struck = the same rule as the pad's (``strike_success``): the fist's impulse, no contact
    before the task window, no contact episode longer than ``max_contact_s``."""

    kind = "bag"
    struck = True
    PARAMS = {"bag_mass_kg": 40.0, "bag_x_m": 0.79, "bag_center_z_m": 1.2, "bag_rope_m": 1.0,
              "bag_timeconst_s": 0.01, "strike_impulse_n_s": 3.0, "max_contact_s": 0.3, "min_fist_speed_m_s": 0.0,
              "min_fist_reach": 0.0}
    MODEL_PARAMS = ("bag_mass_kg", "bag_x_m", "bag_center_z_m", "bag_rope_m", "bag_timeconst_s")
    LIMITS = {"bag_mass_kg": Range(0.5, 1000.0, unit="kg"), "bag_x_m": Range(0.2, 5.0, unit="m"),
              # the bag (half its length below its centre) clears the floor; the pivot is above the bag's top
              "bag_center_z_m": Range(BAG_LENGTH_M / 2 + 0.01, 5.0, unit="m"),
              "bag_rope_m": Range(BAG_LENGTH_M / 2, 10.0, unit="m"),
              "bag_timeconst_s": Range(0.004, 1.0, unit="s"),  # at least 2 x the 2 ms physics step
              "strike_impulse_n_s": Range(0.0, 1e4, unit="N s"), "max_contact_s": Range(0.0, 60.0, unit="s"),
              "min_fist_speed_m_s": Range(0.0, 100.0, unit="m/s"), "min_fist_reach": Range(0.0, 1.0)}
    mass_body = "bag"
    every_step = True  # the fist's speed and reach are read at the physics step the contact starts

    @classmethod
    def add_to_spec(cls, spec, p):
        m, rope = p["bag_mass_kg"], p["bag_rope_m"]
        h, t = BAG_LENGTH_M, BAG_THICKNESS_M
        body = spec.worldbody.add_body(name="bag", pos=[p["bag_x_m"] + t / 2, 0, p["bag_center_z_m"] + rope])
        j = body.add_joint(name="bag_swing", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 1, 0])
        j.limited = mujoco.mjtLimited.mjLIMITED_FALSE
        j.armature = 0.0
        inertia = m * (rope**2 + (h**2 + t**2) / 12)  # about the pivot
        j.damping = [2 * BAG_DAMPING_RATIO * math.sqrt(inertia * m * GRAVITY_M_S2 * rope), 0.0, 0.0]
        body.add_geom(name="bag", type=mujoco.mjtGeom.mjGEOM_BOX, size=[t / 2, 0.2, h / 2], pos=[0, 0, -rope],
                      mass=m, contype=1, conaffinity=1, solref=[p["bag_timeconst_s"], 1.0],
                      rgba=[0.55, 0.2, 0.15, 1])
        _hand_touch_sensors(spec)

    def __init__(self, model, params):
        super().__init__(model, params)
        joint = model.joint("bag_swing")
        self.qpos, self.dof = joint.qposadr[0], joint.dofadr[0]
        self.hands = np.array([model.body(f"forearm_{side}").id for side in ("r", "l")])
        self.root = int(model.body_rootid[self.hands[0]])  # cvel is given at this body's subtree CoM
        self.shoulders = np.array([model.body(f"upper_arm_{side}").id for side in ("r", "l")])  # at the shoulder joint
        self.arm_m = float(np.linalg.norm(model.body_pos[self.hands[0]]) + np.linalg.norm(HAND_OFFSET_M))
        self.fist_m_s = np.zeros((0, 2, 2))  # per simulation, each fist's (x, z) velocity at the last step's state
        self.fist_reach = np.zeros((0, 2))  # ... and each fist's reach (fraction of the arm's length)
        self.contact_speed_m_s = np.zeros(0)  # the touching fist's speed at the first contact (NaN: none yet)
        self.contact_reach = np.zeros(0)  # ... and its reach then

    def fields(self):
        return {"xmat"}

    def start(self, batch, b, n, end_qpos, mass_scale=None):
        super().start(batch, b, n, end_qpos, mass_scale)
        self.fist_m_s = np.full((n, 2, 2), np.nan)
        self.fist_reach = np.full((n, 2), np.nan)
        self.contact_speed_m_s = np.full(n, np.nan)
        self.contact_reach = np.full(n, np.nan)

    def settle_hold(self, b):
        b["qpos"][:, self.qpos] = 0.0
        b["qvel"][:, self.dof] = 0.0

    def step(self, batch, b, ids, t):
        """Every physics step: the touch sensors hold the force of the step just taken, which started from the
        state the fists' velocities were last read at; the first step with a force on a hand is the contact,
        and that hand's speed and reach then are the fist's at contact. Then read those of the state now."""
        waiting = ids[np.isnan(self.contact_speed_m_s[ids])]
        if waiting.size == 0:
            return
        force = b["sensordata"][waiting][:, self.sensors]  # (rows, 2): right, left
        hit = force.max(axis=1) > CONTACT_FORCE_N
        if hit.any():
            rows = waiting[hit]
            side = np.argmax(force[hit], axis=1)
            self.contact_speed_m_s[rows] = np.hypot(*self.fist_m_s[rows, side].T)
            self.contact_reach[rows] = self.fist_reach[rows, side]
            waiting = waiting[~hit]
        self.fist_m_s[waiting] = fist_velocity(b, waiting, self.hands, self.root)
        self.fist_reach[waiting] = fist_reach(b, waiting, self.hands, self.shoulders, self.arm_m)

    def extras(self, b, rows):
        """How fast the bag swings away now (m/s at its centre; + = away from the character), and the speed of
        the fist that first touched it, at that instant (m/s; NaN: no contact), and that fist's reach then (its
        distance from the shoulder as a fraction of the arm's length)."""
        return {"bag_speed_m_s": -b["qvel"][rows, self.dof] * self.params["bag_rope_m"],
                "fist_speed_at_contact_m_s": self.contact_speed_m_s[rows],
                "fist_reach_at_contact": self.contact_reach[rows]}

    def success(self, b, rows, contact_force_n, times, window):
        """The strike rule (``strike_success``), and the fist met the bag at ``min_fist_speed_m_s`` or faster (a
        punch, not a push) with the arm extended to ``min_fist_reach`` of its length or more (a punch, not a lean
        that smothers it)."""
        struck = strike_success(contact_force_n, times, window, self.params["strike_impulse_n_s"],
                                self.params["max_contact_s"])
        fast = np.nan_to_num(self.contact_speed_m_s[rows]) >= self.params["min_fist_speed_m_s"] - 1e-9
        reached = np.nan_to_num(self.contact_reach[rows]) >= self.params["min_fist_reach"] - 1e-9
        return struck & fast & reached


#: The prop kinds a task file may name, each its class.
PROPS: dict[str, type[Prop]] = {cls.kind: cls for cls in (Ball, Slab, Pad, Bag)}


def prop_class(kind: str | None) -> type[Prop]:
    """The class of a task's prop (``Prop`` itself for a task without one)."""
    return Prop if kind is None else PROPS[kind]


def model_values(kind: str | None, params: dict[str, float]) -> tuple[tuple[str, float], ...]:
    """The task parameters that change the compiled model, as a hashable key for ``build_model``: the prop's, and
    the floor's friction where a task sets it (``cmrt.body.surface``)."""
    return tuple((k, float(params[k])) for k in sorted(prop_class(kind).MODEL_PARAMS)) + surface.model_values(params)


def build_model(kind: str | None, values: tuple[tuple[str, float], ...] = (), body: str = "planar") -> mujoco.MjModel:
    """The humanoid (``body``, a key of ``cmrt.body.character.BODIES``) plus one prop (or none), compiled once per
    distinct parameter set. A prop is the same on both bodies: its joints are planar (x, z, pitch) in the sagittal
    plane y = 0, where the 3D body's sagittal motion plays the planar one's (``cmrt.body.sagittal``)."""
    return _build_model(kind, values, body)


@functools.lru_cache(maxsize=32)
def _build_model(kind: str | None, values: tuple[tuple[str, float], ...], body: str) -> mujoco.MjModel:
    spec = mujoco.MjSpec.from_file(str(BODIES[body][0]))
    surface.add_to_spec(spec, dict(values))
    if kind is not None:
        if kind not in PROPS:
            raise ValueError(kind)
        PROPS[kind].add_to_spec(spec, dict(values))
    try:
        return spec.compile()
    except ValueError as exc:  # MuJoCo's compiler: the parameters' ranges should make this unreachable
        raise CmrtError(f"cannot build the {kind} model from {dict(values)}: {str(exc).splitlines()[0]}") from None


def strike_success(force_n: np.ndarray, times: np.ndarray, window: tuple[float, float], impulse_n_s: float,
                   max_contact_s: float) -> np.ndarray:
    """Per row of ``force_n`` (n, steps): a strike in [start, end] of at least ``impulse_n_s``, nothing
    touching before ``start``, and no contact episode longer than ``max_contact_s``."""
    dt = float(times[1] - times[0])
    f = np.nan_to_num(force_n)
    touching = f > CONTACT_FORCE_N
    inside = (times >= window[0]) & (times <= window[1])
    impulse = (f * inside).sum(axis=1) * dt
    early = (touching & (times < window[0])).any(axis=1)
    longest = np.array([_longest_run(row) for row in touching]) * dt
    return (impulse >= impulse_n_s) & ~early & (longest <= max_contact_s)


def _longest_run(flags: np.ndarray) -> int:
    if not flags.any():
        return 0
    edges = np.diff(np.concatenate([[0], flags.astype(np.int8), [0]]))
    return int((np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)).max())
