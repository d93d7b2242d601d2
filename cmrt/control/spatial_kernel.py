"""The 3D controller's arithmetic for one control step, compiled (numba): the formulas of
``cmrt.control.spatial`` (which documents them) without Python between them.

Every quantity comes from MuJoCo's com-based fields as the planar kernel's do (``kernel.centroidal_spatial``,
``kernel.point_frame_spatial``: the centroidal momentum matrix and its bias, the contact points' and the feet's
Jacobians and their rates, checked against ``mj_angmomMat``, ``mj_jac`` and ``mj_jacDot`` in tests/control) and the
joint-space inertia from MuJoCo's sparse one (``d.M``, its rows' columns ``M_colind``); the QP is
``cmrt.control.dual_qp``'s. The rows keep one layout
whatever touches the floor, so the last control step's working set starts the next:

    base dynamics (6) | right foot held (6) | left foot held (6) | per point: floor, four pyramid faces (5 each)
    | each actuated joint's stops | each motor's limits

A foot off the floor has empty rows; a point off the floor carries nothing (f = 0: its first three rows fix its
force, its last two are empty).

A numba pitfall for whoever edits the solver: numba's cache keys a compiled function on its own source file, and
``plan_step`` compiles ``dual_qp.solve`` and the planar kernel's functions into itself - so after editing
``dual_qp.py`` or ``kernel.py`` alone, a cached ``plan_step`` keeps running the old code (measured: a fingerprint of
the 3D clips did not move for an edit of the solver). ``cmrt.sim.spatial_loop.run_clip`` compiles all of them in
again. Delete ``cmrt/control/__pycache__/*.nb*`` and ``cmrt/sim/__pycache__/*.nb*`` before measuring an edit; a
fresh install or CI compiles everything anew.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cmrt.control import dual_qp
from cmrt.control.kernel import centroidal_spatial, point_frame_spatial

N_BASE = 6  # a free root's dofs
# Indices into the gains vector (``SpatialController``): ControllerConfig's, gravity, the point floor
(G_KL, G_DL, G_KT, G_DT, G_BL, G_BH, G_BT, G_EPS, G_MU, G_FLOOR, G_DAMP, G_SW, G_SK, G_SD, G_JK, G_JD,
 G_GRAVITY) = range(17)
N_GAINS = 17
# Indices into the targets vector: the CoM's reference (x, y, z) and rate, the CoP's reference (x, y), swing foot
# (-1 none) and its path (position, velocity), the held mass (kg; 0 none) and where it is, the body's mass (kg, with
# what the forearms carry)
(T_COM, T_VEL, T_COP, T_SWING, T_SWING_POS, T_SWING_VEL, T_HELD, T_HELD_AT, T_MASS) = (0, 3, 6, 8, 9, 12, 15, 16, 19)
N_TARGETS = 20


def n_rows(n_act: int, n_points: int) -> int:
    """The QP's rows in ``plan_step``'s layout."""
    return 3 * N_BASE + 5 * n_points + 2 * n_act


@njit(cache=True, nogil=True)
def write_targets(targets, com_ref, com_xy, com_vel, cop, swing, swing_pos, swing_vel, held_kg, mass
                  ):  # pragma: no cover - compiled
    """A control step's targets into ``plan_step``'s vector (its ``T_*`` layout): the CoM held (3) with its
    horizontal reference ``com_xy`` over it, the reference's rate (2; 0 up), the CoP's reference (2), the swing foot
    (-1 none) and, for a foot in the air, its path and rate (3 each), the held mass (kg; 0 none; where it is is the
    caller's) and the body's mass (kg)."""
    targets[T_COM:T_COM + 3] = com_ref
    targets[T_COM:T_COM + 2] = com_xy
    targets[T_VEL], targets[T_VEL + 1], targets[T_VEL + 2] = com_vel[0], com_vel[1], 0.0
    targets[T_COP:T_COP + 2] = cop
    targets[T_SWING] = swing
    if swing >= 0:
        targets[T_SWING_POS:T_SWING_POS + 3] = swing_pos
        targets[T_SWING_VEL:T_SWING_VEL + 3] = swing_vel
    targets[T_HELD] = held_kg
    targets[T_MASS] = mass


@njit(cache=True, nogil=True)
def plan_step(fields, body, gains, targets, refs, loaded, load_gen, held_bodies, history, count, active
              ):  # pragma: no cover - compiled
    """One control step's plan: (torques per actuator, forces per point (n, 3), the planned CoP (2), the QP's
    status, whether the plan is within the motors' limits - where no plan is, the limits' rows are left out and the
    torques clipped after the solve, as a fall's last steps need).

    ``fields``: (cdof, cdof_dot, cvel, cinert, qpos, qvel, M, qfrc_bias, subtree_com, geom_xpos, xpos, xquat) of the
    clip's MjData (a prop's bodies and dofs after the humanoid's are not read). ``body``: (chain, m_rows, m_cols,
    act_dofs, act_qpos, stop_lo, stop_hi, torque_limit, gear, point_geoms, point_bodies, point_drop, foot_bodies,
    foot_points). ``refs``: (q_ref (nq), qd_ref (nv), qdd_ref (nv)). ``history`` (delay + 1, 6): the CoM and its
    velocity of the last control steps, ``count`` (1,) how many were written; the plan feeds back the oldest kept.
    ``active``: the QP's working set, carried to the next step."""
    cdof, cdof_dot, cvel, cinert, qpos, qvel, M_sparse, qfrc_bias, subtree_com, geom_xpos, xpos, xquat = fields
    (chain, m_rows, m_cols, act_dofs, act_qpos, stop_lo, stop_hi, torque_limit, gear, point_geoms, point_bodies,
     point_drop, foot_bodies, foot_points) = body
    nv = chain.shape[1]
    n_pts, n_act = point_geoms.size, act_dofs.size
    n = nv + 3 * n_pts
    com = subtree_com[1].copy()
    mass = targets[T_MASS]
    qd = qvel[:nv]
    A, a = centroidal_spatial(cdof, cdof_dot, cvel, cinert, qd, chain)
    # the delayed feedback: this step's CoM and velocity kept, the oldest kept fed back
    depth = history.shape[0]
    slot = count[0] % depth
    for i in range(3):
        history[slot, i] = com[i]
        history[slot, 3 + i] = _dot(A[i], qd) / mass
    count[0] += 1
    oldest = 0 if count[0] <= depth else count[0] % depth
    ldot = np.zeros(3)
    for i in range(2):
        ldot[i] = (gains[G_KL] * mass * (targets[T_COM + i] - history[oldest, i])
                   + gains[G_DL] * mass * (targets[T_VEL + i] - history[oldest, 3 + i]))
    force = np.array([ldot[0], ldot[1], mass * gains[G_GRAVITY]])
    r = np.array([targets[T_COP] - com[0], targets[T_COP + 1] - com[1], -com[2]])
    hdot = np.array([r[1] * force[2] - r[2] * force[1], r[2] * force[0] - r[0] * force[2],
                     r[0] * force[1] - r[1] * force[0]])
    swing = int(targets[T_SWING])
    on = loaded.copy()
    if swing >= 0:
        for k in range(foot_points.shape[1]):
            on[foot_points[swing, k]] = False
    Jp = _point_jacobians(cdof, chain, point_geoms, point_bodies, point_drop, geom_xpos, com)
    H1, f = _objective(A, a, ldot, hdot, qpos, qd, refs, act_dofs, act_qpos, stop_lo, stop_hi, gains, n)
    if swing >= 0:
        _swing_objective(cdof, cdof_dot, cvel, qd, chain, foot_bodies[swing], xpos, xquat, com, targets, gains,
                         H1, f)
    M, bias = _dynamics(M_sparse, m_rows, m_cols, qfrc_bias, load_gen, nv)
    if targets[T_HELD] > 0.0:
        _holding(cdof, cdof_dot, cvel, qd, chain, held_bodies, targets, com, gains, M, bias)
    rows, lo, hi, equality, span = _rows(cdof, cdof_dot, cvel, qpos, qd, chain, body, gains, M, bias, Jp, on, com,
                                         xpos, n)
    h2 = np.full(n - nv, 2.0 * gains[G_EPS])
    x, status, _ = dual_qp.solve_spanned(H1, h2, f, rows, lo, hi, equality, active, span)
    limited = status == dual_qp.OPTIMAL
    if not limited:
        lo[-n_act:], hi[-n_act:] = -np.inf, np.inf
        active[:] = dual_qp.INACTIVE
        x, status, _ = dual_qp.solve_spanned(H1, h2, f, rows, lo, hi, equality, active, span)
    if status != dual_qp.OPTIMAL:
        return np.zeros(n_act), np.zeros((n_pts, 3)), np.full(2, np.nan), status, limited
    torque = np.empty(n_act)
    for k in range(n_act):
        j = act_dofs[k]
        tau = _dot(M[j], x[:nv]) + bias[j]
        for p in range(3 * n_pts):
            tau -= Jp[p, j] * x[nv + p]
        torque[k] = min(max(tau, -torque_limit[k]), torque_limit[k]) / gear[k]
    forces = x[nv:].reshape(n_pts, 3).copy()
    fz, cop = 0.0, np.zeros(2)
    for p in range(n_pts):
        fz += forces[p, 2]
        cop[0] += forces[p, 2] * geom_xpos[point_geoms[p], 0]
        cop[1] += forces[p, 2] * geom_xpos[point_geoms[p], 1]
    if fz > 1e-9:
        cop /= fz
    else:
        cop[:] = np.nan
    return torque, forces, cop, status, limited


@njit(cache=True, nogil=True, inline="always")
def _dot(a, b):  # pragma: no cover - compiled
    """a . b as a plain loop in order (numba's np.dot calls BLAS: dearer than these short sums). Not the solver's
    ``dual_qp._dot``, which may reassociate (fastmath): the kernel's sums keep IEEE order."""
    s = 0.0
    for i in range(a.size):
        s += a[i] * b[i]
    return s


@njit(cache=True, nogil=True)
def _point_jacobians(cdof, chain, point_geoms, point_bodies, point_drop, geom_xpos, com):  # pragma: no cover
    """The contact points' translational Jacobians stacked (3 n, nv), at each sphere's lowest point: a com-based
    twist (omega, v) moves a point r from the CoM at v + omega x r."""
    nv = chain.shape[1]
    J = np.zeros((3 * point_geoms.size, nv))
    for p in range(point_geoms.size):
        g, b = point_geoms[p], point_bodies[p]
        rx, ry, rz = geom_xpos[g, 0] - com[0], geom_xpos[g, 1] - com[1], geom_xpos[g, 2] - point_drop[p] - com[2]
        for j in range(nv):
            if chain[b, j]:
                w0, w1, w2 = cdof[j, 0], cdof[j, 1], cdof[j, 2]
                J[3 * p, j] = cdof[j, 3] + (w1 * rz - w2 * ry)
                J[3 * p + 1, j] = cdof[j, 4] + (w2 * rx - w0 * rz)
                J[3 * p + 2, j] = cdof[j, 5] + (w0 * ry - w1 * rx)
    return J


@njit(cache=True, nogil=True)
def _objective(A, a, ldot, hdot, qpos, qd, refs, act_dofs, act_qpos, stop_lo, stop_hi, gains, n
               ):  # pragma: no cover - compiled
    """The cost's qdd block H_1 (nv, nv) and its linear term f (n,), both doubled (daqp's 1/2 x'Hx + f'x): the
    momentum rates, the joints' tracking (the reference's rate and acceleration fed forward), a small
    regularization."""
    nv = A.shape[1]
    q_ref, qd_ref, qdd_ref = refs
    H = np.zeros((nv, nv))
    f = np.zeros(n)
    want = np.empty(5)
    weight = np.empty(5)
    rows = (0, 1, 3, 4, 5)
    for k in range(5):
        i = rows[k]
        weight[k] = gains[G_BL] if i < 3 else gains[G_BH]
        want[k] = (ldot[i] - a[i]) if i < 3 else (hdot[i - 3] - a[i])
    for k in range(5):
        i = rows[k]
        for c in range(nv):
            aw = weight[k] * A[i, c]
            f[c] -= 2.0 * aw * want[k]
            for e in range(c, nv):
                H[c, e] += 2.0 * aw * A[i, e]
    for k in range(act_dofs.size):
        j, qa = act_dofs[k], act_qpos[k]
        target = min(max(q_ref[qa], stop_lo[k]), stop_hi[k])
        des = gains[G_KT] * (target - qpos[qa]) - gains[G_DT] * qd[j] + gains[G_DT] * qd_ref[j] + qdd_ref[j]
        H[j, j] += 2.0 * gains[G_BT]
        f[j] -= 2.0 * gains[G_BT] * des
    for c in range(nv):
        H[c, c] += 2.0 * gains[G_EPS]
        for e in range(c + 1, nv):
            H[e, c] = H[c, e]
    return H, f


@njit(cache=True, nogil=True)
def _swing_objective(cdof, cdof_dot, cvel, qd, chain, foot, xpos, xquat, com, targets, gains, H, f
                     ):  # pragma: no cover - compiled
    """A lifted foot's frame toward its path, level (the rotation back to level: the axis-angle of the frame's
    inverse quaternion, MuJoCo's ``mju_subQuat`` from level), into the cost in place."""
    nv = chain.shape[1]
    J, bias = point_frame_spatial(cdof, cdof_dot, cvel, qd, chain[foot], foot, xpos[foot], com)
    w, x, y, z = xquat[foot, 0], -xquat[foot, 1], -xquat[foot, 2], -xquat[foot, 3]
    s = np.sqrt(x * x + y * y + z * z)
    level = np.zeros(3)
    if s > 0.0:  # mju_quat2Vel: the axis times the angle, wrapped into (-pi, pi]
        angle = 2.0 * np.arctan2(s, w)
        if angle > np.pi:
            angle -= 2.0 * np.pi
        level[0], level[1], level[2] = x / s * angle, y / s * angle, z / s * angle
    vel = np.empty(6)
    for i in range(6):
        vel[i] = _dot(J[i], qd)
    want = np.empty(6)
    for i in range(3):
        want[i] = (gains[G_SK] * (targets[T_SWING_POS + i] - xpos[foot, i])
                   + gains[G_SD] * (targets[T_SWING_VEL + i] - vel[i])) - bias[i]
        want[3 + i] = gains[G_SK] * level[i] - gains[G_SD] * vel[3 + i] - bias[3 + i]
    scale = 2.0 * gains[G_SW]
    for i in range(6):
        for c in range(nv):
            jw = scale * J[i, c]
            if jw != 0.0:
                f[c] -= jw * want[i]
                for e in range(nv):
                    H[c, e] += jw * J[i, e]


@njit(cache=True, nogil=True)
def _dynamics(M_sparse, m_rows, m_cols, qfrc_bias, load_gen, nv):  # pragma: no cover - compiled
    """The joint-space inertia (nv, nv) from MuJoCo's sparse M (the humanoid's block), and the bias forces less a
    held load's generalized force."""
    M = np.zeros((nv, nv))
    for k in range(m_rows.size):
        i, j = m_rows[k], m_cols[k]
        if i < nv and j < nv:
            M[i, j] = M_sparse[k]
            M[j, i] = M_sparse[k]
    bias = np.empty(nv)
    for j in range(nv):
        bias[j] = qfrc_bias[j] - load_gen[j]
    return M, bias


@njit(cache=True, nogil=True)
def _holding(cdof, cdof_dot, cvel, qd, chain, held_bodies, targets, com, gains, M, bias):  # pragma: no cover
    """A point mass carried by the hands in the dynamics, in place (``SpatialController._holding`` says why): its
    point's Jacobian J and acceleration bias, the means over the bodies holding it, add m J'J to the inertia and
    m J'(Jdot qd - g) to the bias."""
    nv = chain.shape[1]
    mass = targets[T_HELD]
    point = targets[T_HELD_AT:T_HELD_AT + 3].copy()
    J = np.zeros((3, nv))
    rate = np.zeros(3)
    for b in held_bodies:
        Jb, bias_b = point_frame_spatial(cdof, cdof_dot, cvel, qd, chain[b], b, point, com)
        for i in range(3):
            J[i] += Jb[i] / held_bodies.size
            rate[i] += bias_b[i] / held_bodies.size
    rate[2] += gains[G_GRAVITY]
    for c in range(nv):
        s = 0.0
        for i in range(3):
            s += J[i, c] * rate[i]
            for e in range(nv):
                M[c, e] += mass * J[i, c] * J[i, e]
        bias[c] += mass * s


@njit(cache=True, nogil=True)
def _rows(cdof, cdof_dot, cvel, qpos, qd, chain, body, gains, M, bias, Jp, on, com, xpos, n
          ):  # pragma: no cover - compiled
    """The QP's rows (A, lo, hi, equality, each row's nonzero span) in the module's layout; a row's span is
    scanned only where its nonzeros can be (``dual_qp.row_span``: the same span a scan of the whole row finds)."""
    (_, _, _, act_dofs, act_qpos, stop_lo, stop_hi, torque_limit, _, point_geoms, _, _, foot_bodies,
     foot_points) = body
    nv, n_pts, n_act = chain.shape[1], point_geoms.size, act_dofs.size
    m = 3 * N_BASE + 5 * n_pts + 2 * n_act
    A = np.zeros((m, n))
    lo, hi = np.full(m, -np.inf), np.full(m, np.inf)
    equality = np.zeros(m, np.bool_)
    span = np.empty((m, 2), np.int64)
    for r in range(N_BASE):  # M_base qdd - J_base' f = -h_base
        A[r, :nv] = M[r]
        for p in range(3 * n_pts):
            A[r, nv + p] = -Jp[p, r]
        lo[r] = hi[r] = -bias[r]
        equality[r] = True
    for foot in range(2):  # a supporting foot stays where it is
        carried = False
        for k in range(foot_points.shape[1]):
            carried = carried or on[foot_points[foot, k]]
        if not carried:
            continue
        b = foot_bodies[foot]
        J, rate = point_frame_spatial(cdof, cdof_dot, cvel, qd, chain[b], b, xpos[b], com)
        for i in range(6):
            r = N_BASE * (1 + foot) + i
            A[r, :nv] = J[i]
            lo[r] = hi[r] = -rate[i] - gains[G_DAMP] * _dot(J[i], qd)
            equality[r] = True
    for r in range(N_BASE):
        dual_qp.row_span(A, r, 0, n, span)
    for r in range(N_BASE, 3 * N_BASE):  # empty where the foot is not carried
        dual_qp.row_span(A, r, 0, nv, span)
    at = 3 * N_BASE
    mu = gains[G_MU]
    for p in range(n_pts):
        fx, fy, fz = nv + 3 * p, nv + 3 * p + 1, nv + 3 * p + 2
        r = at + 5 * p
        if on[p]:  # its floor, and MuJoCo's pyramid scaled: +-f_x +-f_y <= mu f_z
            A[r, fz] = 1.0
            lo[r] = gains[G_FLOOR]
            for face in range(4):
                A[r + 1 + face, fx] = 1.0 if face < 2 else -1.0
                A[r + 1 + face, fy] = 1.0 if face % 2 == 0 else -1.0
                A[r + 1 + face, fz] = -mu
                hi[r + 1 + face] = 0.0
        else:  # carries nothing
            for c in range(3):
                A[r + c, nv + 3 * p + (2 - c)] = 1.0
                lo[r + c] = hi[r + c] = 0.0
                equality[r + c] = True
        for c in range(5):  # a point's rows touch its own force only
            dual_qp.row_span(A, r + c, fx, fz + 1, span)
    at += 5 * n_pts
    for k in range(n_act):  # each joint approaches its stops no faster than a critically damped spring
        j, qa = act_dofs[k], act_qpos[k]
        A[at + k, j] = 1.0
        low = -gains[G_JK] * (qpos[qa] - stop_lo[k]) - gains[G_JD] * qd[j]
        high = -gains[G_JK] * (qpos[qa] - stop_hi[k]) - gains[G_JD] * qd[j]
        lo[at + k] = low if np.isfinite(low) else -np.inf
        hi[at + k] = high if np.isfinite(high) else np.inf
        dual_qp.row_span(A, at + k, j, j + 1, span)
    at += n_act
    for k in range(n_act):  # tau = M_a qdd + h_a - J_a' f within the motor's limit
        j = act_dofs[k]
        A[at + k, :nv] = M[j]
        for p in range(3 * n_pts):
            A[at + k, nv + p] = -Jp[p, j]
        lo[at + k] = -torque_limit[k] - bias[j]
        hi[at + k] = torque_limit[k] - bias[j]
        dual_qp.row_span(A, at + k, 0, n, span)
    return A, lo, hi, equality, span
