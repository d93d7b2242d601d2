"""The floating box's coupling (cmrt.body.floating_box) against a real MuJoCo box body on spring-damper water.

A block stands off-centre on a box lighter than itself and is pushed. Simulated once in the world (the box a body
with three joints, its water the joints' springs and dampers, the block in contact with its deck) and once as
CMRT simulates it: the block on the plane z = 0 of the deck's frame, feeling the deck's motion as a field
(``frame_field``), the box integrated beside MuJoCo from the block's contact load (``FloatingBox``). The two
agree within 1.1 mm and 0.11 degrees while the box tilts 8 degrees and drifts 25 mm (measured at 4, 2, 1 and
0.5 ms steps: the difference does not shrink with the step, it is the one step the load lags at the start and the
joints' implicit damping, not a drift); without the added-mass term the box sinks 21 cm and tilts 21 degrees.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

import cmrt.body.floating_box as fb
from cmrt.body.character import GRAVITY_M_S2
from cmrt.body.surface import frame_field, uniform_field

BOX_KG = 10.0  # lighter than the block: the case a plain lagged coupling cannot take
BLOCK_KG = 30.0
STIFFNESS_N_M = 4000.0
DAMPING_RATIO = 0.3
START_X_M = 0.12  # the block stands this far ahead of the deck's centre: the box tilts
PUSH_N, PUSH_FROM_S, PUSH_TO_S = 60.0, 0.5, 0.6
DURATION_S = 1.5
BLOCK_HALF_M = (0.1, 0.05)  # half length, half height
BALL_M = 0.02  # contact spheres at the block's bottom corners (one contact each, on a box or a plane alike)

BLOCK = f"""
    <body name="block" pos="{START_X_M} 0 {BLOCK_HALF_M[1] + BALL_M - 0.0005}">
      <joint type="slide" axis="1 0 0"/><joint type="slide" axis="0 0 1"/><joint type="hinge" axis="0 1 0"/>
      <inertial pos="0 0 0" mass="{BLOCK_KG}" diaginertia="0.1 0.1 0.1"/>
      <geom type="box" size="{BLOCK_HALF_M[0]} 0.1 {BLOCK_HALF_M[1]}" contype="0" conaffinity="0"/>
      <geom type="sphere" size="{BALL_M}" pos="{-BLOCK_HALF_M[0]} 0 {-BLOCK_HALF_M[1]}"/>
      <geom type="sphere" size="{BALL_M}" pos="{BLOCK_HALF_M[0]} 0 {-BLOCK_HALF_M[1]}"/>
    </body>"""


def _box() -> fb.FloatingBox:
    inertia = 0.1 + BLOCK_KG * START_X_M ** 2
    return fb.FloatingBox(1, BOX_KG, STIFFNESS_N_M, DAMPING_RATIO, BLOCK_KG, inertia, 0.002)


def _model(world: bool, timestep_s: float) -> mujoco.MjModel:
    opt = f'<option timestep="{timestep_s}" cone="elliptic" impratio="100" integrator="Euler"/>'
    if not world:
        return mujoco.MjModel.from_xml_string(
            f'<mujoco>{opt}<worldbody><geom name="floor" type="plane" size="5 5 0.1"/>{BLOCK}</worldbody></mujoco>')
    box = _box()
    k_z, k_pitch = box.stiffness[1], box.stiffness[2]
    c_x, c_z, c_pitch = box.damping
    inertia = box.box_inertia[2, 2]
    springref = (BOX_KG + BLOCK_KG) * GRAVITY_M_S2 / k_z  # buoyancy carries box and block at z = 0
    w, h = fb.BOX_WIDTH_M / 2, fb.BOX_HEIGHT_M / 2
    return mujoco.MjModel.from_xml_string(f"""<mujoco>{opt}<worldbody>
    <body name="box">
      <joint type="slide" axis="1 0 0" damping="{c_x}"/>
      <joint type="slide" axis="0 0 1" stiffness="{k_z}" springref="{springref}" damping="{c_z}"/>
      <joint type="hinge" axis="0 1 0" stiffness="{k_pitch}" damping="{c_pitch}"/>
      <inertial pos="0 0 0" mass="{BOX_KG}" diaginertia="{inertia} {inertia} {inertia}"/>
      <geom type="box" size="{w} 0.5 {h}" pos="0 0 {-h}"/>
    </body>{BLOCK}</worldbody></mujoco>""")


def _push(d: mujoco.MjData, body: int, t_s: float) -> None:
    d.xfrc_applied[body, 0] += PUSH_N if PUSH_FROM_S <= t_s < PUSH_TO_S else 0.0


def _world(timestep_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(steps, 3) box pose (x, z, theta) and (steps, 2) block CoM in the world."""
    m = _model(True, timestep_s)
    d = mujoco.MjData(m)
    block = m.body("block").id
    box, com = [], []
    for _ in range(int(round(DURATION_S / timestep_s))):
        d.xfrc_applied[:] = 0.0
        _push(d, block, d.time)
        mujoco.mj_step(m, d)
        box.append(d.qpos[:3].copy())
        com.append(d.xipos[block, [0, 2]].copy())
    return np.array(box), np.array(com)


def _in_deck_frame(timestep_s: float, added_mass: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The same, as CMRT simulates it: the block in the deck's frame, the box beside MuJoCo."""
    m = _model(False, timestep_s)
    d = mujoco.MjData(m)
    block = m.body("block").id
    box = _box()
    box.dt = timestep_s
    mass, inertia = np.array([0.0, BLOCK_KG]), np.array([0.0, 0.1])
    poses, com, anchor = [], [], None
    for k in range(int(round(DURATION_S / timestep_s))):
        mujoco.mj_forward(m, d)
        if k > 0:  # the load of the step just taken (as _SupportField.update)
            wrench = fb.contact_wrench(d.qfrc_constraint[None, :3], anchor)
            rigid = (np.array([BLOCK_KG]), d.xipos[None, block, [0, 2]], np.array([0.1]))
            if not added_mass:
                rigid = (np.zeros(1), rigid[1], np.zeros(1))
            box.advance(np.array([0]), wrench, *rigid)
        anchor = d.xpos[None, block, [0, 2]].copy()
        theta, omega, alpha, acc = box.frame(np.array([0]))
        ux, uz = uniform_field(theta, acc)
        pos = d.xipos[None, :, [0, 2]]
        vel = np.zeros_like(pos)
        vel[0, block] = d.qvel[:2]
        f = frame_field(omega[:, None], alpha[:, None], ux[:, None], uz[:, None], pos, vel, mass, inertia)[0]
        d.xfrc_applied[:] = 0.0
        d.xfrc_applied[:, 0], d.xfrc_applied[:, 2], d.xfrc_applied[:, 4] = f[:, 0], f[:, 1], f[:, 2]
        _push(d, block, d.time)
        if not np.isfinite(d.xfrc_applied).all() or abs(box.q[0, 2]) > 1.0:
            return np.array(poses), np.full((len(poses), 2), np.inf)
        mujoco.mj_step(m, d)
        # where the box is now: the step's acceleration moved it (advance's first half, without the next load)
        v = box.v[0] + timestep_s * box.a[0]
        q = box.q[0] + timestep_s * v
        c, s = math.cos(q[2]), math.sin(q[2])
        x, z = d.xipos[block, 0], d.xipos[block, 2]
        poses.append(q)
        com.append([c * x + s * z + q[0], -s * x + c * z + q[1]])
    return np.array(poses), np.array(com)


@pytest.mark.parametrize("timestep_s", [0.004, 0.002, 0.001])
def test_the_box_and_block_move_as_a_real_box_body_carrying_it(timestep_s):
    world_box, world_com = _world(timestep_s)
    deck_box, deck_com = _in_deck_frame(timestep_s)
    # it is a real motion: the off-centre block tilts the box, the push moves both
    assert np.degrees(np.abs(world_box[:, 2]).max()) > 1.0
    assert np.abs(world_com[:, 0] - world_com[0, 0]).max() > 0.01
    assert np.abs(deck_box[:, 2] - world_box[:, 2]).max() < math.radians(0.2)
    assert np.abs(deck_box[:, :2] - world_box[:, :2]).max() < 2e-3
    assert np.abs(deck_com - world_com).max() < 2e-3


def test_without_the_added_mass_the_lagged_coupling_goes_wrong():
    """Why ``FloatingBox`` moves the load's rigid inertia to the left side: a box a third of its load's mass."""
    world_box, _ = _world(0.002)
    deck_box, _ = _in_deck_frame(0.002, added_mass=False)
    assert np.abs(deck_box[:, 1] - world_box[:, 1]).max() > 0.05


def test_the_contact_wrench_is_taken_about_the_deck_centre():
    w = fb.contact_wrench(np.array([[10.0, 700.0, 3.0]]), np.array([[0.2, 0.9]]))
    # moment about the origin = about the anchor + r x F (y): r_z F_x - r_x F_z
    assert w[0, 2] == pytest.approx(3.0 + 0.9 * 10.0 - 0.2 * 700.0)
