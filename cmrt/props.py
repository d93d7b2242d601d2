"""Task props added to the character's model: a thrown ball, a domino slab, a wall pad.

A task file names its prop in ``[prop] kind = "..."``; the prop's numbers live in the
task's ``[params]`` (so ``--set ball_mass_kg=1`` works) and the model is rebuilt (and
cached per process) for each distinct set of them. Props are appended after the
humanoid with ``MjSpec``, so every humanoid body, joint, dof, geom and sensor keeps its
index and the controller works on the leading slices of the batch arrays.

* ``ball``: a sphere on planar joints (slide x, slide z, hinge y), thrown at the hands at
  ``ball_speed_m_s``. It flies level (``gravcomp = 1``) so its arrival point and time
  are set exactly by the task; when its centre comes within reach of the right hand a
  ``connect`` equality (inactive in the model) is switched on for that simulation with
  its anchor at the ball's current position, and gravity is given back to the ball: the
  hands now hold 7 kg. Catching is modelled as a grip, not as friction between two
  capsules and a sphere, which a planar model cannot hold.
* ``slab``: a ``slab_mass_kg`` block standing on the floor in front of the character,
  hinged at its far bottom edge; it topples when pushed past that edge.
* ``wall``: a fixed pad at ``wall_x_m`` in front of the character (a punching target);
  its contact stiffness is ``wall_timeconst_s``.
"""

from __future__ import annotations

import functools

import mujoco
import numpy as np

from cmrt.character import MODEL_PATH

PROP_KINDS = ("ball", "slab", "wall")
BALL_RADIUS_M = 0.12
HAND_OFFSET_M = np.array([0.0, 0.0, -0.40])  # forearm frame -> fingertip end of the capsule
CATCH_MARGIN_M = 0.03

#: Task parameters each prop reads when the model is built, with defaults.
PROP_PARAMS: dict[str, dict[str, float]] = {
    "ball": {"ball_mass_kg": 7.0, "ball_speed_m_s": 4.0, "ball_arrival_s": 1.35, "ball_height_m": 1.36,
             "ball_reach_m": 0.86},
    "slab": {"slab_mass_kg": 140.0, "slab_x_m": 0.62, "slab_thickness_m": 0.08, "slab_height_m": 1.9},
    "wall": {"wall_x_m": 0.58, "wall_timeconst_s": 0.01},
}


def _free_planar(body, prefix: str) -> None:
    for name, jtype, axis in ((f"{prefix}_x", mujoco.mjtJoint.mjJNT_SLIDE, [1, 0, 0]),
                              (f"{prefix}_z", mujoco.mjtJoint.mjJNT_SLIDE, [0, 0, 1]),
                              (f"{prefix}_pitch", mujoco.mjtJoint.mjJNT_HINGE, [0, 1, 0])):
        j = body.add_joint(name=name, type=jtype, axis=axis)
        j.limited = mujoco.mjtLimited.mjLIMITED_FALSE
        j.armature = 0.0


@functools.lru_cache(maxsize=32)
def build_model(kind: str | None, values: tuple[tuple[str, float], ...] = ()) -> mujoco.MjModel:
    """The humanoid plus one prop (or none), compiled once per distinct parameter set."""
    spec = mujoco.MjSpec.from_file(str(MODEL_PATH))
    p = dict(values)
    if kind == "ball":
        body = spec.worldbody.add_body(name="ball", pos=[p["ball_reach_m"], 0, p["ball_height_m"]], gravcomp=1.0)
        _free_planar(body, "ball")
        body.add_geom(name="ball", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[BALL_RADIUS_M, 0, 0],
                      mass=p["ball_mass_kg"], contype=1, conaffinity=1, rgba=[0.8, 0.3, 0.1, 1])
        for side in ("r", "l"):  # both hands grip: the load is shared by the two arms
            spec.add_equality(name=f"catch_{side}", type=mujoco.mjtEq.mjEQ_CONNECT, name1=f"forearm_{side}",
                              name2="ball", objtype=mujoco.mjtObj.mjOBJ_BODY, active=False)
    elif kind == "slab":
        t, h = p["slab_thickness_m"], p["slab_height_m"]
        body = spec.worldbody.add_body(name="slab", pos=[p["slab_x_m"] + t, 0, 0])  # frame at the far bottom edge
        j = body.add_joint(name="slab_tip", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 1, 0])
        j.limited = mujoco.mjtLimited.mjLIMITED_FALSE
        j.armature = 0.0
        body.add_geom(name="slab", type=mujoco.mjtGeom.mjGEOM_BOX, size=[t / 2, 0.35, h / 2],
                      pos=[-t / 2, 0, h / 2 + 0.002], mass=p["slab_mass_kg"], contype=1, conaffinity=1,
                      rgba=[0.5, 0.5, 0.6, 1])
    elif kind == "wall":
        # in a body of its own (fixed, no joints): geoms of the world body itself would be
        # numbered before the humanoid's and shift their indices
        body = spec.worldbody.add_body(name="wall", pos=[p["wall_x_m"] + 0.05, 0, 1.3])
        body.add_geom(name="wall", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.05, 0.4, 0.4], contype=1,
                      conaffinity=1, solref=[p["wall_timeconst_s"], 1.0], rgba=[0.3, 0.3, 0.8, 1])
    elif kind is not None:
        raise ValueError(kind)
    return spec.compile()


def model_values(kind: str | None, params: dict[str, float]) -> tuple[tuple[str, float], ...]:
    if kind is None:
        return ()
    return tuple((k, float(params[k])) for k in sorted(PROP_PARAMS[kind]))


class PropRuntime:
    """Per-clip behaviour of a prop inside the batched simulation loop."""

    def __init__(self, kind: str | None, model: mujoco.MjModel, params: dict[str, float]):
        self.kind, self.model, self.params = kind, model, params
        if kind == "ball":
            self.ball_body = model.body("ball").id
            self.ball_dofs = slice(model.joint("ball_x").dofadr[0], model.joint("ball_x").dofadr[0] + 3)
            self.ball_qpos = slice(model.joint("ball_x").qposadr[0], model.joint("ball_x").qposadr[0] + 3)
            self.hand_body = model.body("forearm_r").id
            self.hand_bodies = (model.body("forearm_r").id, model.body("forearm_l").id)
        if kind == "slab":
            self.slab_qpos = model.joint("slab_tip").qposadr[0]

    def fields(self) -> set[str]:
        return {"ball": {"xmat", "eq_active"}, "wall": {"xmat"}}.get(self.kind, set())

    def settle_hold(self, b: dict) -> None:
        """Keep the prop still while the character settles."""
        if self.kind == "ball":
            b["qvel"][:, self.ball_dofs] = 0.0

    def start(self, batch, b: dict) -> None:
        """Set the prop going at the start of the clip (the ball is thrown)."""
        if self.kind == "ball":
            p = self.params
            start_x = p["ball_reach_m"] + p["ball_speed_m_s"] * p["ball_arrival_s"]
            b["qpos"][:, self.ball_qpos] = [start_x - p["ball_reach_m"], 0.0, 0.0]
            b["qvel"][:, self.ball_dofs] = [-p["ball_speed_m_s"], 0.0, 0.0]
            self.eq_data = batch.expand("eq_data")
            self.gravcomp = batch.expand("body_gravcomp")
            self.caught = np.zeros(b["qpos"].shape[0], bool)

    def control_step(self, b: dict, ids: np.ndarray) -> None:
        """Called before each control step: the catch; the punch's hit."""
        if self.kind == "wall":
            if not hasattr(self, "hit"):
                self.hit = np.zeros(b["qpos"].shape[0], bool)
            hand_body = self.model.body("forearm_r").id
            R = b["xmat"][ids, hand_body].reshape(-1, 3, 3)
            tip = b["xpos"][ids, hand_body] + R @ HAND_OFFSET_M
            self.hit[ids] |= tip[:, 0] + 0.035 >= self.params["wall_x_m"] - 0.002  # fist (capsule end) at the pad
            return
        if self.kind != "ball":
            return
        ids = ids[~self.caught[ids]]
        if ids.size == 0:
            return
        hand_origin = b["xpos"][ids, self.hand_body]
        R = b["xmat"][ids, self.hand_body].reshape(-1, 3, 3)
        hand = hand_origin + R @ HAND_OFFSET_M
        ball = b["xpos"][ids, self.ball_body]
        near = np.hypot(ball[:, 0] - hand[:, 0], ball[:, 2] - hand[:, 2]) < BALL_RADIUS_M + CATCH_MARGIN_M
        for i in np.flatnonzero(near):
            sim = ids[i]
            for eq, body in enumerate(self.hand_bodies):
                Rb = b["xmat"][sim, body].reshape(3, 3)
                self.eq_data[sim, eq, 0:3] = Rb.T @ (ball[i] - b["xpos"][sim, body])  # anchor in the forearm frame
                self.eq_data[sim, eq, 3:6] = 0.0  # the ball's centre
                b["eq_active"][sim, eq] = 1.0
            self.gravcomp[sim, self.ball_body] = 0.0
            self.caught[sim] = True

    def success(self, b: dict) -> np.ndarray | None:
        """Per simulation: was the task's goal reached? None for pure pose changes."""
        n = b["qpos"].shape[0]
        if self.kind == "ball":
            held = b["xpos"][:, self.ball_body, 2] > 0.5
            return self.caught & held
        if self.kind == "slab":
            return b["qpos"][:, self.slab_qpos] > np.radians(30)  # toppled well past its edge
        if self.kind == "wall":
            return self.hit if hasattr(self, "hit") else np.zeros(n, bool)
        return None
