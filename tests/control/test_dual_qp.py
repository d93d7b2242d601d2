"""The 3D plan's QP solver (cmrt.control.dual_qp) against daqp, the general dual active-set solver it replaced: the
same optimum on random problems of the plan's shape from any starting working set, infeasibility found where daqp
finds it, and the plan's own QPs solved as daqp solves them."""

import daqp
import mujoco
import numpy as np
import pytest

from cmrt.body.character import character
from cmrt.control import dual_qp
from cmrt.control import spatial_kernel as sk
from cmrt.control.spatial import SpatialController, SpatialTargets
from cmrt.sim.spatial import BODY, stand_pose_qpos

EQUALITY = 5  # daqp's sense of an equality row


def _daqp(H1, h2, f, A, lo, hi, equality):
    """daqp's answer on the whole cost (its x and exit flag)."""
    n1 = H1.shape[0]
    H = np.zeros((f.size, f.size))
    H[:n1, :n1] = H1
    H[n1:, n1:] = np.diag(h2)
    sense = np.where(equality, EQUALITY, 0).astype(np.int32)
    x, _, flag, _ = daqp.solve(H, f, A, hi, np.where(equality, hi, lo), sense)
    return x, flag


def _random_problem(rng, n1=12, n2=9, m=30, n_eq=4):
    """A problem of the plan's shape: a dense block and a diagonal one, dense and sparse rows (a few on the forces
    alone, as the contact rows are), some equalities, bounds around a feasible point (some one-sided, some tight)."""
    B = rng.standard_normal((n1, n1))
    H1 = B @ B.T + 0.1 * np.eye(n1)
    h2 = rng.uniform(0.01, 1.0, n2)
    n = n1 + n2
    f = rng.standard_normal(n) * 10
    A = rng.standard_normal((m, n))
    for i in range(n_eq, m, 3):  # sparse rows on the forces alone
        A[i, :n1] = 0.0
        A[i, n1:] *= rng.random(n2) < 0.3
        A[i, n1 + rng.integers(n2)] = 1.0
    x0 = rng.standard_normal(n)
    ax = A @ x0
    lo = ax - rng.uniform(0.0, 1.0, m)
    hi = ax + rng.uniform(0.0, 1.0, m)
    lo[rng.random(m) < 0.2] = -np.inf
    hi[rng.random(m) < 0.2] = np.inf
    equality = np.zeros(m, bool)
    equality[:n_eq] = True
    lo[:n_eq] = hi[:n_eq] = ax[:n_eq]
    return H1, h2, f, A, lo, hi, equality


@pytest.mark.parametrize("seed", range(40))
def test_the_optimum_is_daqps_from_any_start(seed):
    rng = np.random.default_rng(seed)
    problem = _random_problem(rng)
    expected, flag = _daqp(*problem)
    assert flag >= 1
    scale = max(1.0, float(np.abs(expected).max()))
    for start in (np.zeros(30, np.int8), rng.choice([-1, 0, 1], 30).astype(np.int8)):  # cold; a wrong warm start
        active = start.copy()
        x, status, _ = dual_qp.solve(*problem, active)
        assert status == dual_qp.OPTIMAL
        np.testing.assert_allclose(x, expected, rtol=0, atol=1e-7 * scale)
        again = active.copy()  # the solution's working set starts the same problem at its optimum: no iteration
        x2, status2, iterations = dual_qp.solve(*problem, again)
        assert status2 == dual_qp.OPTIMAL and iterations == 0
        np.testing.assert_allclose(x2, x, rtol=0, atol=1e-9 * scale)


def test_contradicting_rows_are_infeasible_as_daqp_finds():
    rng = np.random.default_rng(7)
    H1, h2, f, A, lo, hi, equality = _random_problem(rng)
    A[10] = A[11]  # the same row bounded apart: a x >= 1 and a x <= -1
    lo[10], hi[10] = 1.0, np.inf
    lo[11], hi[11] = -np.inf, -1.0
    _, flag = _daqp(H1, h2, f, A, lo, hi, equality)
    assert flag < 1
    x, status, _ = dual_qp.solve(H1, h2, f, A, lo, hi, equality, np.zeros(30, np.int8))
    assert status == dual_qp.INFEASIBLE


def test_a_row_of_zeros_is_skipped_or_infeasible():
    rng = np.random.default_rng(8)
    H1, h2, f, A, lo, hi, equality = _random_problem(rng)
    A[12] = 0.0
    lo[12], hi[12] = -np.inf, np.inf
    x, status, _ = dual_qp.solve(H1, h2, f, A, lo, hi, equality, np.zeros(30, np.int8))
    assert status == dual_qp.OPTIMAL
    np.testing.assert_allclose(x, _daqp(H1, h2, f, A, lo, hi, equality)[0], atol=1e-7 * max(1, np.abs(x).max()))
    lo[12] = 1.0  # 0 >= 1
    assert dual_qp.solve(H1, h2, f, A, lo, hi, equality, np.zeros(30, np.int8))[1] == dual_qp.INFEASIBLE


def test_a_cost_that_is_not_convex_is_refused():
    rng = np.random.default_rng(9)
    H1, h2, f, A, lo, hi, equality = _random_problem(rng)
    H1[0, 0] = -1.0
    assert dual_qp.solve(H1, h2, f, A, lo, hi, equality, np.zeros(30, np.int8))[1] == dual_qp.NOT_CONVEX


def _plan_qp(ctl: SpatialController, d: mujoco.MjData, loaded: np.ndarray, targets: SpatialTargets):
    """The QP ``ctl`` solves for this control step, built by the kernel's own parts."""
    ctl.plan(d, loaded, targets)  # fills the targets vector and the history as the step does
    t, body, gains = ctl._targets, ctl._body, ctl._gains
    chain, nv = body[0], ctl.nv
    qd = d.qvel[:nv].copy()
    com = d.subtree_com[1].copy()
    A, a = sk.centroidal_spatial(d.cdof, d.cdof_dot, d.cvel, d.cinert, qd, chain)
    on = loaded.copy()
    if targets.swing_foot >= 0:
        on[body[13][targets.swing_foot]] = False
    Jp = sk._point_jacobians(d.cdof, chain, body[9], body[10], body[11], d.geom_xpos, com)
    refs = (ctl.q_ref if targets.q_ref is None else targets.q_ref, ctl._still, ctl._still)
    ldot = np.array([0.3, -0.2, 0.0]) * ctl.mass_kg
    hdot = np.array([1.0, 2.0, 0.5])
    H1, f = sk._objective(A, a, ldot, hdot, d.qpos, qd, refs, body[3], body[4], body[5], body[6], gains,
                          nv + 3 * len(ctl.points))
    if targets.swing_foot >= 0:
        sk._swing_objective(d.cdof, d.cdof_dot, d.cvel, qd, chain, body[12][targets.swing_foot], d.xpos, d.xquat,
                            com, t, gains, H1, f)
    M, bias = sk._dynamics(d.M, body[1], body[2], d.qfrc_bias, ctl._still, nv)
    rows, lo, hi, equality, span = sk._rows(d.cdof, d.cdof_dot, d.cvel, d.qpos, qd, chain, body, gains, M, bias, Jp,
                                            on, com, d.xpos, nv + 3 * len(ctl.points))
    # the spans the plan hands the solver are those a scan of every whole row finds
    np.testing.assert_array_equal(span, dual_qp.spans(rows))
    return H1, np.full(3 * len(ctl.points), 2.0 * gains[sk.G_EPS]), f, rows, lo, hi, equality


@pytest.mark.parametrize("case", ["both feet", "right foot lifting"])
def test_the_plans_qp_is_solved_as_daqp_solves_it(case):
    """The 3D plan's own QP - 55 unknowns, 108 rows: the base's dynamics and the feet held (equalities), each
    point's floor and friction pyramid, the joints' stops and the motors' limits - solved by this module and by
    daqp: the same accelerations and forces, to daqp's tolerance."""
    ch = character(BODY)
    d = mujoco.MjData(ch.model)
    d.qpos[:] = stand_pose_qpos()
    d.qvel[:] = 0.05 * np.random.default_rng(3).standard_normal(ch.model.nv)
    mujoco.mj_forward(ch.model, d)
    ctl = SpatialController(ch, d.qpos.copy())
    targets = SpatialTargets()
    if case != "both feet":
        targets = SpatialTargets(cop_xy_m=np.array([0.06, 0.09]), swing_foot=0,
                                 swing_pos_m=d.xpos[ch.foot_bodies[0]] + [0.0, 0.0, 0.05], swing_vel_m_s=np.zeros(3))
    problem = _plan_qp(ctl, d, np.ones(len(ch.foot_point_geoms), bool), targets)
    assert problem[3].shape == (108, 55)
    expected, flag = _daqp(*problem)
    assert flag >= 1
    x, status, _ = dual_qp.solve(*problem, np.zeros(108, np.int8))
    assert status == dual_qp.OPTIMAL
    np.testing.assert_allclose(x, expected, rtol=0, atol=1e-7 * np.abs(expected).max())
