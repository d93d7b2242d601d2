"""A task's prop in a 3D clip: the planar props (``cmrt.body.props``), unchanged, over one MjData.

The props are written for the planar lockstep batch: they read and write per-simulation arrays (``b[field][rows,
...]``) and per-simulation model fields (``batch.expand``, ``batch.set_const``). ``PropClip`` gives them that
interface over the 3D clip's one MjData and its own copy of the model (views with a leading axis of one), so a
caught ball grips, is held and is judged by the same code on both bodies. On the 3D body the ball is free in space
(a free joint, ``Ball.spatial``: its hands may squeeze it, the world may not hold it up or apart). What the hands
hold reaches the 3D plan in the form the per-point plan can use: a gripped ball carried - its mass moving with the
hands (``carried``) - and any other held load as MuJoCo's own constraint force on the body (``load``). What falls
counts a held ball's mass at its x and z, in the plane y = 0 it is dropped in (``with_held``).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from cmrt.body.character import character
from cmrt.body.props import CONTACT_FORCE_N, prop_class


@dataclass(frozen=True)
class HeldProp:
    """What a 3D clip needs of its task's prop: its kind, the task's parameters, the compiled model of body and
    prop (``Task.model``), the task's end pose (qpos), the window its goal is judged in (s) and its mass as a
    multiple of the task's (a robust ensemble's member: ``Prop.start`` scales it on the clip's own model)."""

    kind: str
    params: dict[str, float]
    model: mujoco.MjModel
    end_qpos: np.ndarray
    window_s: tuple[float, float]
    mass_scale: float = 1.0


class PropClip:
    """One clip's prop through the batch interface a prop is written for: ``expand`` and ``set_const`` on the
    clip's own model, the data's fields as (1, ...) views. The prop's contact force is recorded every physics step
    (``record``) and its goal judged once, at the clip's end or at a fall (``judge``; a fall freezes it, as on the
    planar body)."""

    def __init__(self, held: HeldProp, m: mujoco.MjModel, d: mujoco.MjData):
        self.m, self.d, self.window_s = m, d, held.window_s
        self.prop = prop_class(held.kind)(m, held.params)
        self.first_prop_body = character("humanoid3d").model.nbody  # the prop's bodies come after the humanoid's
        names = {"qpos", "qvel", "qacc", "xpos", "xmat", "sensordata", "subtree_com", "cvel"} | self.prop.fields()
        self.b = {k: getattr(d, k)[None] for k in names}
        self.ids = np.zeros(1, np.int64)
        self.force_n: list[float] = []  # the hands' force on the prop, every physics step (N)
        self.goal: bool | None = None  # judged: the prop's goal met (None: not yet)
        self.extras: dict[str, float] = {}
        self.prop.start(self, self.b, 1, held.end_qpos, np.array([held.mass_scale]))

    def expand(self, name: str) -> np.ndarray:
        """The clip's own model field as its one simulation's row (writes reach the model)."""
        return getattr(self.m, name)[None]

    def set_const(self) -> None:
        """The model's derived constants after a prop changed a mass (``mj_setConst``, on a scratch MjData: it
        poses its data at qpos0)."""
        mujoco.mj_setConst(self.m, mujoco.MjData(self.m))

    def step(self, t: float, control: bool) -> None:
        """Before the physics step at ``t``: the prop's own per-step behaviour (a release, a grip)."""
        if control or self.prop.every_step:
            self.prop.step(self, self.b, self.ids, t)

    def record(self) -> None:
        """After a physics step: the hands' force on the prop over it."""
        force = self.prop.contact_force(self.b, slice(None))
        self.force_n.append(float(force[0]) if force is not None else 0.0)

    def leaning(self) -> bool:
        """The hands are on a prop that holds the body up (a slab): the pendulum's capture point does not apply."""
        return self.prop.holds_body_up and bool(self.force_n) and self.force_n[-1] > CONTACT_FORCE_N

    def load(self, nv: int) -> np.ndarray | None:
        """What a prop the character holds (one with a ``Prop.hand_load``: a ball, a slab) put on the body over the
        last physics step, as a generalized force on the humanoid's ``nv`` dofs: MuJoCo's own constraint forces of
        the rows that join the prop to the body - a grip's equalities, the prop's contacts - through their
        Jacobian (``mj_mulJacTVec``). Each hand's share as it is, a squeeze between the hands included, where the
        planar kernel takes the prop's net force shared equally. None: nothing held."""
        if self.prop.hand_load(self.b, self.ids) is None:
            return None
        m, d = self.m, self.d
        kind, ids, first = d.efc_type, d.efc_id, self.first_prop_body
        rows = np.zeros(d.nefc, bool)
        grip = kind == int(mujoco.mjtConstraint.mjCNSTR_EQUALITY)
        rows[grip] = np.maximum(m.eq_obj1id[ids[grip]], m.eq_obj2id[ids[grip]]) >= first
        touch = kind >= int(mujoco.mjtConstraint.mjCNSTR_CONTACT_FRICTIONLESS)
        if touch.any():
            bodies = m.geom_bodyid[d.contact.geom[ids[touch]]]  # (rows, 2): a hand on the prop, not the floor
            rows[touch] = (bodies.max(axis=1) >= first) & (bodies.min(axis=1) > 0)
        gen = np.zeros(m.nv)
        mujoco.mj_mulJacTVec(m, d, gen, np.where(rows, d.efc_force, 0.0))
        return gen[:nv]

    def carried(self, mass_kg: float) -> tuple[float, np.ndarray, tuple[int, ...]]:
        """A held mass (``held``'s kg) as the plan carries it: kg, where it is (world, m) and the bodies holding it
        equally (``Prop.hand_load``'s)."""
        _, point, bodies = self.prop.hand_load(self.b, self.ids)
        return mass_kg, np.asarray(point[0], float), tuple(int(b) for b in bodies)

    def held(self) -> tuple[float, np.ndarray, float, float] | None:
        """A mass the hands hold that the body does not carry (kg), its (x, z), its x velocity and the share of it
        the controller balances now (``Prop.held_mass``); None: nothing held."""
        held = self.prop.held_mass(self.b, self.ids)
        if held is None or not held[0][0] > 0.0:
            return None
        mass, xz, vx, share = held
        return float(mass[0]), np.asarray(xz[0], float), float(vx[0]), float(share[0])

    def judge(self, dt_s: float) -> None:
        """The prop's goal and figures now (once: the first call, at a fall or at the clip's end)."""
        if self.goal is not None:
            return
        times = force_times_s(len(self.force_n), dt_s)
        verdict = self.prop.success(self.b, self.ids, np.array(self.force_n)[None], times, self.window_s)
        self.goal = bool(verdict[0]) if verdict is not None else True
        self.extras = {k: float(v[0]) for k, v in self.prop.extras(self.b, self.ids).items()}


def force_times_s(n: int, step_s: float) -> np.ndarray:
    """When each of ``n`` recorded hand-prop forces was measured (s): each is the physics step's that ends then."""
    return (np.arange(n) + 1) * step_s


def with_held(com: np.ndarray, vel: np.ndarray, body_kg: float,
              held: tuple[float, np.ndarray, float, float] | None) -> tuple[np.ndarray, np.ndarray]:
    """The CoM (3,) and its velocity (3,) of the body with what its hands hold and it does not carry (``held``:
    ``PropClip.held``): what balances and falls, as the planar monitor counts it; the held mass is in the plane
    y = 0, where the prop's joints keep it, at rest across it."""
    if held is None:
        return com, vel
    mass, xz, vx, _ = held
    total = body_kg + mass
    com, vel = com.copy(), vel.copy()
    com[0] = (body_kg * com[0] + mass * xz[0]) / total
    com[1] = body_kg * com[1] / total
    com[2] = (body_kg * com[2] + mass * xz[1]) / total
    vel[0] = (body_kg * vel[0] + mass * vx) / total
    vel[1] = body_kg * vel[1] / total
    return com, vel


def balancing_held(com_x_m: float, body_kg: float, held: tuple[float, np.ndarray, float, float] | None) -> float:
    """The CoM target's x moved so that the body and the share of a held mass the controller balances stand over
    it together: c_b = c_r - w m (x_held - c_r) / M_body (the planar ``_balancing_held``'s rule)."""
    if held is None or held[3] <= 0.0:
        return com_x_m
    mass, xz, _, share = held
    return com_x_m - share * mass * (xz[0] - com_x_m) / body_kg
