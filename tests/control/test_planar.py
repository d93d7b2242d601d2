"""``cmrt.control.planar`` on every task model, batched, row by row against MuJoCo's own quantities.

What planar.py models: the humanoid's *root subtree* (body 1, the trunk that carries the root
slide-x / slide-z / pitch joints), not body 0. Props are appended after the humanoid as trees of
their own (``body_rootid`` of a prop body is the prop itself), so the world's subtree 0 also holds
the ball (catch: 82 kg), the slab (push: 210 kg) and the pad (punch: 134 kg). MuJoCo's com-based
fields of the humanoid's bodies (``cinert``, ``cvel``, ``cdof``) are centred on
``subtree_com[body_rootid] = subtree_com[1]``: the humanoid's CoM. So ``PlanarKinematics`` is
built from the humanoid model alone (as the controller and the simulator build it), is applied to
the leading ``[:, :nbody]`` / ``[:, :nv]`` slices of a task model's batch fields, and its momentum
is the humanoid's centroidal momentum: MuJoCo's ``subtree_linvel[1]`` times
``body_subtreemass[1]`` and ``subtree_angmom[1]`` (about ``subtree_com[1]``).

States: per task ``N_STATES`` random (qpos, qvel) around the task's start pose, props' coordinates
and velocities random too (a moving prop must not leak into the humanoid's momentum), and
``N_LOADED`` more rows whose forearms carry extra mass per simulation (``Batch.expand`` +
``set_const``, as a caught ball's mass is handed to the forearms) so that per-simulation inertias
are covered. They are computed in one ``mujoco.batch.Batch`` forward at the velocity stage, as in
``cmrt.simulate``; each row's reference is a separate ``MjData`` of ``batch.get_model(i)``
(``mj_forward``, ``mj_subtreeVel``, ``mj_jac*``).

Tolerances. Quantities MuJoCo computes in closed form are compared to ``EXACT_RTOL`` = 1e-9 of the
largest reference entry of the row: both sides are the same double-precision sums in a different
order (measured worst case over all rows: 1.5e-15; the mass matrix and the point Jacobians agree
bit for bit), while any wrong index, body, frame or sign is an error of order 1 (a 1e-7 change of
one body's mass in ``cinert`` already fails). Momentum *rates* (the biases ``Adot qd``) have no
MuJoCo closed form; they are compared with a 4th-order central difference of MuJoCo's momentum
along ``q + t qd`` (every joint here is a slide or a hinge, nq == nv) with step ``FD_STEP_S`` =
3e-4 s, near the optimum of truncation O(h^4) and round-off O(eps / h): measured worst case
1.2e-11 relative (1e-3 s: 2.8e-11, 1e-4 s: 1.1e-10, 1e-2 s: 2.9e-7), so ``FD_RTOL`` = 1e-9 keeps
~100x margin yet fails on a 1e-6 relative change of ``cdof_dot``.
"""

from __future__ import annotations

import functools
import zlib

import mujoco
import mujoco.batch
import numpy as np
import pytest

import cmrt
from cmrt.body.character import FOOT_POINT_RADIUS_M, character
from cmrt.control import kernel
from cmrt.control.momentum import centroidal_momentum_matrix
from cmrt.control.planar import PLANAR, PlanarKinematics

N_STATES = 4  # random states per task model
N_LOADED = 2  # more rows with extra mass in the forearms (a held load), per-simulation model fields
LOAD_KG = 6.0
EXACT_RTOL = 1e-9
ABS_FLOOR = 1e-2  # rows smaller than this are compared to rtol * ABS_FLOOR (see assert_close)
FD_RTOL = 1e-9
FD_STEP_S = 3e-4
FIELDS = ("qpos", "qvel", "cdof", "cdof_dot", "cvel", "cinert", "M", "subtree_com", "geom_xpos")
ALL_TASKS = cmrt.available_tasks()
TASKS = [name for name in ALL_TASKS if cmrt.load_task(name).body == "planar"]  # the planar kernel's tasks


def assert_close(actual, expected, rtol, what):
    """|actual - expected| <= rtol * max|expected| over the row (entries near zero are not singled out); a row
    whose largest entry is below ``ABS_FLOOR`` (a nearly still state) is held to rtol * ABS_FLOOR, which is still
    ~10x the rounding of the chain's sums (measured 1.1e-12 on a punch state whose foot bias was 8e-4)."""
    actual, expected = np.asarray(actual), np.asarray(expected)
    scale = max(np.abs(expected).max(), ABS_FLOOR)
    err = np.abs(actual - expected).max()
    assert err <= rtol * scale, f"{what}: max error {err:.3g} > {rtol:g} x {scale:.3g}"


@functools.cache
def sample(name: str) -> dict:
    """The batch's fields for N_STATES + N_LOADED states of the task model, and a reference MjData per row."""
    task = cmrt.load_task(name)
    m = task.model()
    ch = character()
    nq_h, nv_h = ch.model.nq, ch.model.nv
    n = N_STATES + N_LOADED
    rng = np.random.default_rng([1913, zlib.crc32(name.encode())])
    qpos = np.tile(m.qpos0, (n, 1))
    qpos[:, :nq_h] = task.start_qpos()
    qpos[:, :2] += rng.normal(scale=0.05, size=(n, 2))  # root x, z (m)
    qpos[:, 2:] += rng.normal(scale=0.3, size=(n, m.nq - 2))  # trunk pitch, joints, prop coordinates
    qvel = rng.normal(scale=1.0, size=(n, m.nv))
    batch = mujoco.batch.Batch(m, nsim=n, nthread=1, persistent=True)
    b = {k: batch.bind(k) for k in FIELDS}
    b["qpos"][:], b["qvel"][:] = qpos, qvel
    mass, ipos = batch.expand("body_mass"), batch.expand("body_ipos")
    for side in ("r", "l"):
        body = m.body(f"forearm_{side}").id
        mass[N_STATES:, body] += LOAD_KG
        ipos[N_STATES:, body, 2] -= 0.1  # the load sits towards the hand
    batch.set_const()
    batch.forward(stage=mujoco.mjtStage.mjSTAGE_VEL)
    refs = []
    for i in range(n):
        mi = batch.get_model(i)
        d = mujoco.MjData(mi)
        d.qpos[:], d.qvel[:] = qpos[i], qvel[i]
        mujoco.mj_forward(mi, d)
        mujoco.mj_subtreeVel(mi, d)
        refs.append((mi, d))
    assert refs[-1][0].body_subtreemass[1] == pytest.approx(ch.mass_kg + 2 * LOAD_KG)
    return {"task": task, "model": m, "nv": nv_h, "nb": ch.model.nbody, "n": n,
            "f": {k: b[k].copy() for k in FIELDS}, "refs": refs}


def subtree_momentum(mi, d, body=1):
    """MuJoCo's planar momentum of a subtree, rows (H_y, L_x, L_z) as planar.py orders them."""
    mass = mi.body_subtreemass[body]
    return np.array([d.subtree_angmom[body, 1], mass * d.subtree_linvel[body, 0], mass * d.subtree_linvel[body, 2]])


def momentum_at(mi, q, qd):
    """MuJoCo's humanoid momentum (H_y, L_x, L_z) at state (q, qd)."""
    d = mujoco.MjData(mi)
    d.qpos[:], d.qvel[:] = q, qd
    mujoco.mj_forward(mi, d)
    mujoco.mj_subtreeVel(mi, d)
    return subtree_momentum(mi, d)


def point_velocity(mi, body, local, qd, q):
    """(x, z, pitch) velocity at state (q, qd) of the material point of ``body`` at ``local`` (body frame)."""
    d = mujoco.MjData(mi)
    d.qpos[:], d.qvel[:] = q, qd
    mujoco.mj_kinematics(mi, d)
    mujoco.mj_comPos(mi, d)
    p = d.xpos[body] + d.xmat[body].reshape(3, 3) @ local
    jacp, jacr = np.zeros((3, mi.nv)), np.zeros((3, mi.nv))
    mujoco.mj_jac(mi, d, jacp, jacr, p, body)
    return np.array([jacp[0] @ qd, jacp[2] @ qd, jacr[1] @ qd])


def rate_along_qd(fn, q, qd, h=FD_STEP_S):
    """d/dt fn(q + t qd) at t = 0, 4th-order central difference (slide/hinge joints only: nq == nv)."""
    return (8 * (fn(q + h * qd) - fn(q - h * qd)) - (fn(q + 2 * h * qd) - fn(q - 2 * h * qd))) / (12 * h)


def planar_momentum_matrix(kin, cdof, cinert, nb, nv):
    """(n, nv, 3) A with rows (H_y, L_x, L_z) per dof, batched from planar.py's pieces, as its docstring defines
    it: A[:, j] = sum_b chain[b, j] P_b s_j with s_j the planar part of cdof_j."""
    P = kin.body_inertia(cinert[:, :nb])  # (n, nb, 3, 3)
    s = cdof[:, :nv][..., PLANAR]  # (n, nv, 3)
    return np.einsum("bj,nbkl,njl->njk", kin.chain.astype(float), P, s)


def test_the_humanoid_is_the_leading_part_of_every_task_model():
    """What lets planar.py's humanoid-only structure - and the 3D controller's - run on the leading slices of a task
    model: its body's, whichever it is, then its prop's."""
    assert set(TASKS) >= {"stand", "bend", "rise", "punch", "catch", "push"}
    for name in ALL_TASKS:
        task = cmrt.load_task(name)
        ch = character(task.body)
        h = ch.model
        m = task.model()
        assert (m.nq, m.nv, m.nbody) >= (h.nq, h.nv, h.nbody)
        np.testing.assert_array_equal(m.body_parentid[: h.nbody], h.body_parentid)
        np.testing.assert_array_equal(m.dof_bodyid[: h.nv], h.dof_bodyid)
        np.testing.assert_array_equal(m.body_rootid[1 : h.nbody], 1)  # one tree: the c-frame is subtree_com[1]
        assert np.all(m.body_rootid[h.nbody :] >= h.nbody)  # props are trees of their own
        assert np.all(m.dof_bodyid[h.nv :] >= h.nbody)
        assert m.body_subtreemass[1] == h.body_subtreemass[1] == ch.mass_kg
        kin, full = PlanarKinematics(h), PlanarKinematics(m)
        assert kin.mass == full.mass == ch.mass_kg
        np.testing.assert_array_equal(full.chain[: h.nbody, : h.nv], kin.chain)
        np.testing.assert_array_equal(full.chain[: h.nbody, h.nv :], False)  # prop dofs move no humanoid body
        nnz = kin.m_rows.size
        np.testing.assert_array_equal(full.m_rows[:nnz], kin.m_rows)
        np.testing.assert_array_equal(full.m_cols[:nnz], kin.m_cols)


@pytest.mark.parametrize("name", TASKS)
def test_chain_and_mass_matrix_structure(name):
    """``chain[b, j]`` (dof j moves body b) is exactly the nonzero pattern of MuJoCo's body Jacobians, and the
    sparse mass matrix's leading entries, placed by ``m_rows``/``m_cols``, are the humanoid's block of
    ``mj_fullM`` (which has no coupling to a prop)."""
    s = sample(name)
    kin = PlanarKinematics(character().model)
    nb, nv, m = s["nb"], s["nv"], s["model"]
    for i, (mi, d) in enumerate(s["refs"]):
        moves = np.zeros((nb, m.nv), bool)
        jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        for body in range(nb):
            mujoco.mj_jacBody(mi, d, jacp, jacr, body)
            moves[body] = np.any(jacp != 0, axis=0) | np.any(jacr != 0, axis=0)
        np.testing.assert_array_equal(moves[:, :nv], kin.chain, err_msg=f"row {i}")
        assert not moves[:, nv:].any()
        M = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(mi, d, M)
        dense = np.zeros((nv, nv))
        nnz = kin.m_rows.size
        dense[kin.m_rows, kin.m_cols] = s["f"]["M"][i, :nnz]
        dense[kin.m_cols, kin.m_rows] = s["f"]["M"][i, :nnz]
        assert_close(dense, M[:nv, :nv], EXACT_RTOL, f"{name} row {i}: mass matrix")
        assert not M[:nv, nv:].any()


@pytest.mark.parametrize("name", TASKS)
def test_momentum_matches_mujoco_subtree(name):
    """``momentum`` / ``linear_momentum`` in one batched call = MuJoCo's subtree-1 momentum per row; each body's
    term ``P_b v_b`` = that body's own momentum about the humanoid's CoM from its mass, inertia and CoM velocity."""
    s = sample(name)
    kin = PlanarKinematics(character().model)
    nb, f = s["nb"], s["f"]
    cinert, cvel = f["cinert"][:, :nb], f["cvel"][:, :nb]
    h = kin.momentum(cinert, cvel)  # (n, 3): H_y, L_x, L_z
    lin = kin.linear_momentum(cinert, cvel)  # (n, 2)
    per_body = (kin.body_inertia(cinert) @ cvel[..., PLANAR][..., None])[..., 0]  # (n, nb, 3)
    assert h.shape == (s["n"], 3) and lin.shape == (s["n"], 2)
    for i, (mi, d) in enumerate(s["refs"]):
        ref = subtree_momentum(mi, d)
        what = f"{name} row {i}"
        assert_close(h[i], ref, EXACT_RTOL, f"{what}: momentum")
        assert_close(lin[i], ref[1:], EXACT_RTOL, f"{what}: linear momentum")
        # the frame: the humanoid's CoM (a prop's is elsewhere, and moving, and must not enter)
        assert_close(f["subtree_com"][i, 1], d.subtree_com[1], EXACT_RTOL, f"{what}: CoM")
        if mi.body_subtreemass[0] > mi.body_subtreemass[1]:  # a massive prop: subtree 0 would be the wrong one
            assert np.abs(d.subtree_com[0] - d.subtree_com[1]).max() > 1e-3
            if mi.nv > s["nv"]:  # ... and a moving one (the pad is fixed)
                assert np.abs(subtree_momentum(mi, d, 0)[1:] - ref[1:]).max() > 1e-2 * np.abs(ref).max()
        com = d.subtree_com[1]
        jacp, jacr = np.zeros((3, mi.nv)), np.zeros((3, mi.nv))
        for body in range(1, nb):
            mujoco.mj_jac(mi, d, jacp, jacr, d.xipos[body], body)
            v, w = jacp @ d.qvel, jacr @ d.qvel
            R = d.ximat[body].reshape(3, 3)
            mass = mi.body_mass[body]
            ang = R @ (mi.body_inertia[body] * (R.T @ w)) + np.cross(d.xipos[body] - com, mass * v)
            assert_close(per_body[i, body], [ang[1], mass * v[0], mass * v[2]], EXACT_RTOL, f"{what}: body {body}")
        np.testing.assert_array_equal(per_body[i, 0], 0.0)  # the world


@pytest.mark.parametrize("name", TASKS)
def test_momentum_matrix_and_bias_match_mujoco(name):
    """A (built batched from ``chain``, ``body_inertia`` and ``cdof``) = momentum.py's reference
    (``mj_jacSubtreeCom``/``mj_angmomMat``, prop columns zero); A qd = the momentum; the compiled kernel's
    A is the same and its bias ``Adot qd`` = the rate of MuJoCo's momentum along ``q + t qd``."""
    s = sample(name)
    kin = PlanarKinematics(character().model)
    nb, nv, f = s["nb"], s["nv"], s["f"]
    A_hl = planar_momentum_matrix(kin, f["cdof"], f["cinert"], nb, nv)  # (n, nv, 3)
    A = np.swapaxes(A_hl[..., [1, 2, 0]], 1, 2)  # (n, 3, nv): rows L_x, L_z, H_y as the controller orders them
    momentum = kin.momentum(f["cinert"][:, :nb], f["cvel"][:, :nb])
    for i, (mi, d) in enumerate(s["refs"]):
        what = f"{name} row {i}"
        ref = centroidal_momentum_matrix(mi, d)
        assert_close(A[i], ref[:, :nv], EXACT_RTOL, f"{what}: A")
        assert not ref[:, nv:].any()
        qd = f["qvel"][i, :nv]
        assert_close(A_hl[i].T @ qd, momentum[i], EXACT_RTOL, f"{what}: A qd")
        A_k, bias = kernel.centroidal(f["cdof"][i], f["cdof_dot"][i], f["cvel"][i], f["cinert"][i], qd.copy(),
                                      kin.chain)
        assert_close(A_k, A[i], EXACT_RTOL, f"{what}: kernel A")
        q_all, qd_all = d.qpos.copy(), d.qvel.copy()
        qd_all[nv:] = 0.0  # the prop stays put (its motion does not enter anyway)
        rate = rate_along_qd(functools.partial(momentum_at, mi, qd=qd_all), q_all, qd_all)[[1, 2, 0]]
        assert_close(bias, rate, FD_RTOL, f"{what}: kernel bias Adot qd")


@pytest.mark.parametrize("name", TASKS)
def test_foot_point_frames_match_mujoco(name):
    """The kernel's (x, z, pitch) Jacobians of the four heel/toe contact points on their feet, with the rows of
    ``chain`` the controller passes it, = ``mj_jac``; their biases = the rate of the material point's velocity
    along ``q + t qd``."""
    s = sample(name)
    ch = character()
    kin = PlanarKinematics(ch.model)
    nv, f = s["nv"], s["f"]
    points = np.array(ch.foot_point_geoms)
    bodies = ch.model.geom_bodyid[points]
    for i, (mi, d) in enumerate(s["refs"]):
        qd = f["qvel"][i, :nv].copy()
        q_all, qd_all = d.qpos.copy(), d.qvel.copy()
        qd_all[nv:] = 0.0
        for g, body in zip(points, bodies, strict=True):
            what = f"{name} row {i} geom {g}"
            point = f["geom_xpos"][i, g] - np.array([0.0, 0.0, FOOT_POINT_RADIUS_M])
            J, bias = kernel.point_frame(f["cdof"][i], f["cdof_dot"][i], f["cvel"][i], qd, kin.chain[body], body,
                                         point, f["subtree_com"][i, 1])
            jacp, jacr = np.zeros((3, mi.nv)), np.zeros((3, mi.nv))
            mujoco.mj_jac(mi, d, jacp, jacr, point, body)
            assert_close(J, np.stack([jacp[0], jacp[2], jacr[1]])[:, :nv], EXACT_RTOL, f"{what}: J")
            local = d.xmat[body].reshape(3, 3).T @ (point - d.xpos[body])
            velocity = functools.partial(point_velocity, mi, body, local, qd_all)
            assert_close(bias, rate_along_qd(velocity, q_all, qd_all), FD_RTOL, f"{what}: bias")
