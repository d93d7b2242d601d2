"""The controller's arithmetic for one control step, compiled (numba), one simulation at a time.

The formulas are those of ``cmrt.control.controller`` (which documents them); this module
only evaluates them without Python overhead: per simulation a few thousand flops for the
planar centroidal momentum matrix, foot Jacobians, the QP (an active set over at most
five wrench rows, each pass one dense KKT solve) and the torques. A batch is a loop over
simulations, so a simulation's torques never depend on the others in its batch.

Planar quantities come from MuJoCo's com-based fields (centred on the whole character's
CoM, so spatial momentum there is the centroidal momentum): a body's ``cinert`` maps its
twist (omega_y, v_x, v_z) to (H_y, L_x, L_z) with

    [[I_yy,  m r_z, -m r_x],
     [m r_z, m,      0    ],
     [-m r_x, 0,     m    ]],

``A`` is the chain-masked sum over bodies, its bias ``Adot qd`` is
``sum_b P_b abias_b + v_b x* (P_b v_b)`` with ``abias_b = sum_{dofs j above b} cdof_dot_j qd_j``,
and point Jacobians and biases follow from the same twists. Checked against MuJoCo's
``mj_jacSubtreeCom``/``mj_angmomMat``/``subtree_linvel`` in tests/control.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# Foot support states (also in controller.py).
FLAT, HEEL, TOE, AIR = 0, 1, 2, 3
# Indices into the parameter vector (built by controller.MomentumBalanceController).
(P_KL, P_DL, P_KT, P_DT, P_BL, P_BH, P_BT, P_EPS, P_G, P_MU, P_FMIN, P_DAMP, P_RW, P_RK, P_RD,
 P_RADIUS, P_DUALREG, P_SW, P_SK, P_SD, P_SWT, P_JK, P_JD, P_LIMITS, P_WARM, P_FZMIN) = range(26)
N_PARAMS = 26
# The swing foot's task-space target (cmrt.control.stepping): heel point x, z, foot pitch; their rates
# and accelerations; then the bend added to the stance knee's reference while the foot swings (rad).
# ``swing_foot`` per simulation: -1 (both feet support), 0 (right swings), 1 (left).
N_SWING = 34
S_CROUCH = 9
S_SWING_KNEE = 10  # the bend added to the swing knee's reference (rad; a straight knee cannot lift its foot)
S_SWING_GAINS = 12  # (weight, stiffness 1/s^2, damping 1/s) of this swing's foot objective; 0: the controller's
S_SETTLED = 15  # nonzero: both feet down after a step; S_STANCE.. S_STANCE + 5 then hold the right and left leg's
S_LANDING = 22  # (foot + 1, pitch rad, weight, stiffness 1/s^2, damping 1/s): a foot landed heel first lowers its
# toe toward this pitch (+ toe down, past flat: a heel sunk under the body's weight leaves a foot at pitch 0 with its
# toe still off the floor) instead of the rolling foot's soft return to flat; 0: none
S_HEIGHT = 27  # (CoM height m, its rate m/s and acceleration m/s^2, weight, stiffness 1/s^2, damping 1/s): a vertical
# linear-momentum objective toward that height (a walking plan's; weight 0: none - otherwise the CoM's height is in no
# objective and the legs' tracking sets it)
S_GAIT = 33  # > 0: a walking plan's row (cmrt.control.stepping.GaitPattern): its linear-momentum objective weighs this
# many times the standing one, and the joints are tracked with the gait's weights (the trunk held firmer)
S_STANCE = 16  # (hip, knee, ankle) offsets from the reference to the stance over the landed feet (rad)
S_SWING_TRACKED = 11  # nonzero: the swing leg tracks the reference motion's own swing at full weight (a keyed
# gait, cmrt.control.gait: its knee bends in the reference) instead of leaving the leg to the foot's target
N_INFO = 6  # planned F_x, F_z, CoP x, right foot state, left foot state, torque saturated
N_INEQ = 5  # F_z >= n f_min, two friction rows, two CoP rows


def n_rows(nu: int) -> int:
    """The QP's inequality rows with the limits in the plan (the warm-start arrays' width): the ground's,
    then two torque rows and two joint-stop rows per motor."""
    return N_INEQ + 4 * nu
MAX_PASSES = 8  # active-set passes with the wrench rows alone
# ...and with the motors' limits and the joint stops as rows too (``P_LIMITS``): one row enters or leaves per pass
MAX_PASSES_LIMITS = 40
# A torque beyond its limit by more than this fraction means the QP found no plan within the limits.
LIMIT_SLACK = 1e-6
# A plan solved without the limit rows is kept only if it keeps each of them clear by this (a fraction of a torque
# limit, or rad/s^2 of a joint stop's spring): far beyond rounding, so the whole QP would not have added the row.
LIMIT_CLEARANCE = 1e-6
TOL = 1e-9
# Feet farther apart than this (heel to heel, m) stand in a split stance - only a step gets them there: the
# plan's load is then split with every point's share bounded below (``bounded_shares``). Side by side the
# linear split is kept: the CoP rows already keep it above f_min there, and planted-feet results stay as
# they were, bit for bit.
SPLIT_STANCE_M = 0.05


@njit(cache=True, nogil=True)
def centroidal_spatial(cdof, cdof_dot, cvel, cinert, qvel, chain, full=True):
    """A (6, nv) with rows [L_x, L_y, L_z, H_x, H_y, H_z] and its bias (6,), for one simulation of any body.

    A body's ``cinert`` (I, m r, m) maps a twist (omega, v) to L = m v + omega x m r and H = I omega + m r x v; the
    bias adds v x* (P v): (omega x L, omega x H + v x L). ``full`` False leaves rows L_y, H_x, H_z at zero: a planar
    body's joints (omega_x = omega_z = v_y = 0) keep it in its plane, whatever its H_x and H_z, and its rows L_x,
    L_z, H_y are then summed in the order the planar formulas always were - bit for bit, at the planar cost."""
    nb, nv = chain.shape
    A = np.zeros((6, nv))
    bias = np.zeros(6)
    for b in range(nb):
        ci = cinert[b]
        ixx, iyy, izz, ixy, ixz, iyz = ci[0], ci[1], ci[2], ci[3], ci[4], ci[5]
        cx, cy, cz, m = ci[6], ci[7], ci[8], ci[9]
        a0 = a1 = a2 = a3 = a4 = a5 = 0.0  # the body's bias acceleration, sum of cdof_dot qd above it
        for j in range(nv):
            if chain[b, j]:
                w0, w1, w2, u0, u1, u2 = cdof[j, 0], cdof[j, 1], cdof[j, 2], cdof[j, 3], cdof[j, 4], cdof[j, 5]
                A[0, j] += m * u0 + (w1 * cz - w2 * cy)
                A[2, j] += m * u2 + (w0 * cy - w1 * cx)
                A[4, j] += ixy * w0 + iyy * w1 + iyz * w2 + cz * u0 - cx * u2
                a1 += cdof_dot[j, 1] * qvel[j]
                a3 += cdof_dot[j, 3] * qvel[j]
                a5 += cdof_dot[j, 5] * qvel[j]
                if full:
                    A[1, j] += m * u1 + (w2 * cx - w0 * cz)
                    A[3, j] += ixx * w0 + ixy * w1 + ixz * w2 + cy * u2 - cz * u1
                    A[5, j] += ixz * w0 + iyz * w1 + izz * w2 + cx * u1 - cy * u0
                    a0 += cdof_dot[j, 0] * qvel[j]
                    a2 += cdof_dot[j, 2] * qvel[j]
                    a4 += cdof_dot[j, 4] * qvel[j]
        w0, w1, w2, u0, u1, u2 = cvel[b, 0], cvel[b, 1], cvel[b, 2], cvel[b, 3], cvel[b, 4], cvel[b, 5]
        lx = m * u0 + (w1 * cz - w2 * cy)  # P v
        ly = m * u1 + (w2 * cx - w0 * cz)
        lz = m * u2 + (w0 * cy - w1 * cx)
        hx = ixx * w0 + ixy * w1 + ixz * w2 + cy * u2 - cz * u1
        hy = ixy * w0 + iyy * w1 + iyz * w2 + cz * u0 - cx * u2
        hz = ixz * w0 + iyz * w1 + izz * w2 + cx * u1 - cy * u0
        bias[0] += m * a3 + (a1 * cz - a2 * cy) + (w1 * lz - w2 * ly)
        bias[2] += m * a5 + (a0 * cy - a1 * cx) + (w0 * ly - w1 * lx)
        bias[4] += ixy * a0 + iyy * a1 + iyz * a2 + cz * a3 - cx * a5 + w2 * hx - w0 * hz + u2 * lx - u0 * lz
        if full:
            bias[1] += m * a4 + (a2 * cx - a0 * cz) + (w2 * lx - w0 * lz)
            bias[3] += ixx * a0 + ixy * a1 + ixz * a2 + cy * a5 - cz * a4 + w1 * hz - w2 * hy + u1 * lz - u2 * ly
            bias[5] += ixz * a0 + iyz * a1 + izz * a2 + cx * a4 - cy * a3 + w0 * hy - w1 * hx + u0 * ly - u1 * lx
    return A, bias


@njit(cache=True, nogil=True)
def centroidal(cdof, cdof_dot, cvel, cinert, qvel, chain):
    """A (3, nv) with rows [L_x, L_z, H_y] and its bias (3,), for one simulation of the planar body: the spatial
    rows of the sagittal plane (``cmrt.body.character.PLANAR_ROWS``)."""
    A6, bias6 = centroidal_spatial(cdof, cdof_dot, cvel, cinert, qvel, chain, False)
    return _planar_rows(A6, bias6)


@njit(cache=True, nogil=True)
def _planar_rows(M6, v6):
    """Rows 0, 2, 4 (x, z, pitch: ``cmrt.body.character.PLANAR_ROWS``) of a spatial matrix and vector."""
    M = np.empty((3, M6.shape[1]))
    v = np.empty(3)
    for r in range(3):
        M[r] = M6[2 * r]
        v[r] = v6[2 * r]
    return M, v


@njit(cache=True, nogil=True)
def point_frame_spatial(cdof, cdof_dot, cvel, qvel, chain_row, body, point, com, full=True):
    """Jacobian (6, nv) of the [linear, angular] velocity of a body's frame placed at ``point``, and its bias (6,):
    the point moves at v + omega x r (r from the CoM, the com-based twists' origin) and accelerates, at qdd = 0, at
    alpha_v + alpha_omega x r + omega x v_point. ``full`` False leaves the rows a planar body has no use for (y, roll,
    yaw) at zero and sums x, z and pitch in the order the planar formulas always were (bit for bit)."""
    nv = chain_row.size
    rx, ry, rz = point[0] - com[0], point[1] - com[1], point[2] - com[2]
    J = np.zeros((6, nv))
    a0 = a1 = a2 = a3 = a4 = a5 = 0.0
    for j in range(nv):
        if chain_row[j]:
            w0, w1, w2, u0, u1, u2 = cdof[j, 0], cdof[j, 1], cdof[j, 2], cdof[j, 3], cdof[j, 4], cdof[j, 5]
            J[0, j] = u0 + (w1 * rz - w2 * ry)
            J[2, j] = u2 + (w0 * ry - w1 * rx)
            J[4, j] = w1
            a1 += cdof_dot[j, 1] * qvel[j]
            a3 += cdof_dot[j, 3] * qvel[j]
            a5 += cdof_dot[j, 5] * qvel[j]
            if full:
                J[1, j] = u1 + (w2 * rx - w0 * rz)
                J[3, j] = w0
                J[5, j] = w2
                a0 += cdof_dot[j, 0] * qvel[j]
                a2 += cdof_dot[j, 2] * qvel[j]
                a4 += cdof_dot[j, 4] * qvel[j]
    w0, w1, w2, u0, u1, u2 = cvel[body, 0], cvel[body, 1], cvel[body, 2], cvel[body, 3], cvel[body, 4], cvel[body, 5]
    vpx = u0 + (w1 * rz - w2 * ry)
    vpy = u1 + (w2 * rx - w0 * rz)
    vpz = u2 + (w0 * ry - w1 * rx)
    bias = np.zeros(6)
    bias[0] = a3 + (a1 * rz - a2 * ry) + (w1 * vpz - w2 * vpy)
    bias[2] = a5 + (a0 * ry - a1 * rx) + (w0 * vpy - w1 * vpx)
    bias[4] = a1
    if full:
        bias[1] = a4 + (a2 * rx - a0 * rz) + (w2 * vpx - w0 * vpz)
        bias[3] = a0
        bias[5] = a2
    return J, bias


@njit(cache=True, nogil=True)
def point_frame(cdof, cdof_dot, cvel, qvel, chain_row, body, point, com):
    """Jacobian (3, nv) of (x, z, pitch) of a body's frame placed at ``point``, and its bias (3,): the planar rows
    of ``point_frame_spatial``."""
    J6, bias6 = point_frame_spatial(cdof, cdof_dot, cvel, qvel, chain_row, body, point, com, False)
    return _planar_rows(J6, bias6)


@njit(cache=True, nogil=True)
def bounded_shares(x, carries, cop, lower):
    """Fractions of the vertical load per heel/toe point (x: their x) that sum to 1 with first moment ``cop``,
    closest to equal shares with every carrying point at least ``lower``: an active set on the linear split.

    With the feet apart the linear split asks the far end's point to pull on the floor whenever the CoP
    nears the other foot (CoP 0.52 m on a [-0.06, 0.62] m stance: -7 % on the rear heel, measured), and
    torques computed for that pull lift the heel. The CoP rows keep a distribution with every point at
    f_min feasible; this finds one."""
    share = np.zeros(4)
    pinned = np.zeros(4, np.bool_)
    for _ in range(4):
        rem, rem_m, count, mean = 1.0, cop, 0, 0.0
        for p in range(4):
            if carries[p] and pinned[p]:
                rem -= lower
                rem_m -= lower * x[p]
            elif carries[p]:
                count += 1
                mean += x[p]
        if count == 0:
            break
        mean /= count
        spread = 0.0
        for p in range(4):
            if carries[p] and not pinned[p]:
                spread += (x[p] - mean) ** 2
        worst, low = -1, lower - 1e-12
        for p in range(4):
            if carries[p] and not pinned[p]:
                share[p] = rem / count
                if spread > 1e-12:
                    share[p] += (x[p] - mean) * (rem_m - rem * mean) / spread
                if share[p] < low:
                    worst, low = p, share[p]
        if worst < 0:
            break
        pinned[worst] = True
        share[worst] = lower
    return share


@njit(cache=True, nogil=True)
def solve_qp(Q, g, E, e, C, c, c_on, dual_reg, passes=MAX_PASSES, active=None):
    """min 1/2 x'Qx - g'x  s.t.  E x = e,  C x + c >= 0 (rows with c_on), by a primal active set.

    Each pass solves the KKT system of the equalities and the active inequalities; the most
    violated inactive row is added, or the active row with the most negative multiplier dropped.
    -dual_reg on the multipliers' diagonal makes redundant rows (both feet asking the same
    vertical acceleration of a straight-kneed body) solvable in the least-squares sense.

    ``active`` (ni,) bool, in and out: the rows to start from (a warm start: the previous control step's
    final set, less the rows now off) and, on return, the final set; None: start from none. The solution
    is computed from the final set alone (its KKT system, rows in index order), so a warm start that ends
    on the same set as a cold one gives the same x, bit for bit: it only saves passes."""
    nx, ne, ni = g.size, e.size, c.size
    if active is None:
        active = np.zeros(ni, np.bool_)
    else:
        for k in range(ni):
            active[k] = active[k] and c_on[k]
    order = np.empty(ni, np.int64)
    x = np.zeros(nx)
    for _ in range(passes):
        na = 0
        for k in range(ni):
            if active[k]:
                order[na] = k
                na += 1
        size = nx + ne + na
        K = np.zeros((size, size))
        rhs = np.zeros(size)
        K[:nx, :nx] = Q
        for r in range(ne):
            for j in range(nx):
                K[nx + r, j] = K[j, nx + r] = E[r, j]
            rhs[nx + r] = e[r]
        for a in range(na):
            k = order[a]
            for j in range(nx):
                K[nx + ne + a, j] = K[j, nx + ne + a] = C[k, j]
            rhs[nx + ne + a] = -c[k]
        rhs[:nx] = g
        for d in range(nx, size):
            K[d, d] = -dual_reg
        sol = np.linalg.solve(K, rhs)
        x = sol[:nx]
        worst_lam, drop = 0.0, -1
        for a in range(na):
            lam = -sol[nx + ne + a]  # lam >= 0 at an optimum with this sign convention
            if lam < worst_lam - TOL:
                worst_lam, drop = lam, order[a]
        if drop >= 0:
            active[drop] = False
            continue
        worst, add = 0.0, -1
        for k in range(ni):
            if c_on[k] and not active[k]:
                slack = c[k]
                for j in range(nx):
                    slack += C[k, j] * x[j]
                if slack < worst - TOL:
                    worst, add = slack, k
        if add < 0:
            break
        active[add] = True
    return x


@njit(cache=True, nogil=True)
def _objective(A, a, qd, q, com, mass, mg, params, w2, leg_dofs, swing, i, targets, field_w):
    """The QP's objective (Q, g) of simulation ``i``: the momentum rates (the CoM toward its reference, the CoP's
    angular momentum rate) and the joints' tracking, a swing leg's and a crouch's adjustments included.
    ``targets``: (q_ref, qd_ref, qdd_ref, com_ref_x, com_ref_vel_x, cop_des_x, swing_target), row ``i`` read."""
    q_ref, qd_ref, qdd_ref, com_ref_x, com_ref_vel_x, cop_des_x, swing_target = targets
    nv = A.shape[1]
    L_x = A[0] @ qd
    ldot_x = params[P_KL] * mass * (com_ref_x[i] - com[0]) + params[P_DL] * (mass * com_ref_vel_x[i] - L_x)
    if field_w.size == 0:
        hdot = -com[2] * ldot_x - (cop_des_x[i] - com[0]) * mg
    else:  # the ground gives the rates less the field's wrench; its moment at the desired CoP, plus the field's
        hdot = (-com[2] * (ldot_x - field_w[0]) - (cop_des_x[i] - com[0]) * (mg - field_w[1])) + field_w[2]
    gait = swing_target[i, S_GAIT] > 0.0
    b_l = params[P_BL] * swing_target[i, S_GAIT] if gait else params[P_BL]
    Q = b_l * np.outer(A[0], A[0]) + params[P_BH] * np.outer(A[2], A[2])
    g = b_l * (ldot_x - a[0]) * A[0] + params[P_BH] * (hdot - a[2]) * A[2]
    weights = w2[1] if gait else w2[0]
    for j in range(nv):
        wj = weights[j]
        qr = q_ref[i, j]
        if swing >= 0:
            if j == leg_dofs[swing, 0] or j == leg_dofs[swing, 1] or j == leg_dofs[swing, 2]:
                if swing_target[i, S_SWING_TRACKED] != 0.0:
                    pass
                elif j == leg_dofs[swing, 1] and swing_target[i, S_SWING_KNEE] != 0.0:  # at full extension the
                    qr += swing_target[i, S_SWING_KNEE]  # knee moves the heel along the leg, not up: a bent
                else:  # reference, tracked, lets the foot rise (a walk)
                    wj *= params[P_SWT]  # the swing leg follows its foot's target, not the standing pose
            elif j == leg_dofs[1 - swing, 1]:  # the stance knee bends (hip and ankle share the angle: the
                qr += swing_target[i, S_CROUCH]  # foot stays flat, the trunk upright): a straight stance leg cannot
            elif j == leg_dofs[1 - swing, 0] or j == leg_dofs[1 - swing, 2]:  # lower the hip, and a swing
                qr -= 0.5 * swing_target[i, S_CROUCH]  # foot a hip too high cannot reach the floor
        elif swing_target[i, S_SETTLED] != 0.0:  # both feet down after a step: the legs stand over the feet where
            for leg in range(2):  # they landed (cmrt.body.stance), not in the pose's own straight-hipped stance
                for k in range(3):
                    if j == leg_dofs[leg, k]:
                        qr += swing_target[i, S_STANCE + 3 * leg + k]
        Q[j, j] += params[P_BT] * wj + params[P_EPS]
        g[j] += params[P_BT] * wj * (params[P_KT] * (qr - q[j])
                                     + params[P_DT] * (qd_ref[i, j] - qd[j]) + qdd_ref[i, j])
    w_z = swing_target[i, S_HEIGHT + 3]
    # the CoM's height along its plan: Ldot_z = m (z_r'' + k (z_r - z) + d (z_r' - z')). The angular target above
    # still takes F_z = m g, so while the height moves the CoP it implies is off by F_z / (m g) - 1 of (p - c_x)
    # (the walk's ground force stays within 0.8-1.4 body weights); the QP's own CoP follows its wrench, and the plan
    # gap stays 1.6-3.2 mm in the walk (docs/stepping.md)
    if w_z > 0.0:
        ldot_z = mass * (swing_target[i, S_HEIGHT + 2] + swing_target[i, S_HEIGHT + 4] * (swing_target[i, S_HEIGHT]
                                                                                         - com[2])
                         + swing_target[i, S_HEIGHT + 5] * (swing_target[i, S_HEIGHT + 1] - (A[1] @ qd) / mass))
        Q += w_z * np.outer(A[1], A[1])
        g += w_z * (ldot_z - a[1]) * A[1]
    return Q, g


@njit(cache=True, nogil=True)
def _loaded_points(state, pts):
    """Which of the four contact points carry load in the feet's states, how many (at least 1), and their
    mean x and spread (the sum of squared deviations) - the inverse dynamics' split of the ground force."""
    carries = np.zeros(4, np.bool_)
    for foot in range(2):
        carries[2 * foot] = state[foot] == FLAT or state[foot] == HEEL
        carries[2 * foot + 1] = state[foot] == FLAT or state[foot] == TOE
    count = max(1, carries.sum())
    mean = 0.0
    for p in range(4):
        if carries[p]:
            mean += pts[p, 0]
    mean /= count
    spread = 0.0
    for p in range(4):
        if carries[p]:
            spread += (pts[p, 0] - mean) ** 2
    return carries, count, mean, spread


@njit(cache=True, nogil=True)
def _dense_dynamics(row, M_sparse, m_rows, m_cols, qfrc_bias, qfrc_passive, nv):
    """Batch row ``row``'s joint-space inertia, dense (nv, nv) from MuJoCo's sparse M, and its bias less
    passive forces, h = qfrc_bias - qfrc_passive."""
    M = np.zeros((nv, nv))
    for k in range(m_rows.size):
        M[m_rows[k], m_cols[k]] = M_sparse[row, k]
        M[m_cols[k], m_rows[k]] = M_sparse[row, k]
    h = np.empty(nv)
    for j in range(nv):
        h[j] = qfrc_bias[row, j] - qfrc_passive[row, j]
    return M, h


@njit(cache=True, nogil=True)
def _contact_points(frame, qd, chain, points, point_bodies, geom_xpos_row, radius, com):
    """The four contact points (the spheres' bottoms: heel_r, toe_r, heel_l, toe_l) and their frames
    (Jacobian and bias, :func:`point_frame`). ``frame``: the row's (cdof, cdof_dot, cvel)."""
    cdof_r, cdof_dot_r, cvel_r = frame
    nv = qd.size
    pts = np.empty((4, 3))
    Jp = np.empty((4, 3, nv))
    bp = np.empty((4, 3))
    for p in range(4):
        pts[p] = geom_xpos_row[points[p]]
        pts[p, 2] -= radius
        Jp[p], bp[p] = point_frame(cdof_r, cdof_dot_r, cvel_r, qd, chain[point_bodies[p]], point_bodies[p],
                                   pts[p], com)
    return pts, Jp, bp


@njit(cache=True, nogil=True)
def _foot_states(contact_row, swing):
    """FLAT, HEEL, TOE or AIR per foot from its points' contacts; the swinging foot is AIR (lifted by the plan,
    whatever it touches now: no support, no load)."""
    state = np.empty(2, np.int64)
    for foot in range(2):
        heel, toe = contact_row[2 * foot], contact_row[2 * foot + 1]
        state[foot] = FLAT if heel and toe else (HEEL if heel else (TOE if toe else AIR))
        if foot == swing:
            state[foot] = AIR
    return state


@njit(cache=True, nogil=True)
def _support_rows(state, frames, qd, q, params, leg_dofs, swing, swing_target_row, Q, g):
    """The supporting feet's contact-anchor equality rows (E, e; a flat foot 3, a rolling one 2), the support
    interval (lo, hi) and how many feet are flat and points load. Into the objective (Q, g, in place): the
    swing foot's task-space terms (heel point x, z and pitch toward the swing plan) and, for a foot that is
    neither flat nor swinging, a soft return-to-flat pitch target. ``frames``: (pts, Jp, bp)."""
    pts, Jp, bp = frames
    nv = qd.size
    E = np.empty((9, nv))
    e = np.empty(9)
    ne = 0
    lo, hi = np.inf, -np.inf
    n_flat, n_points = 0, 0
    for foot in range(2):
        s = state[foot]
        heel, toe = 2 * foot, 2 * foot + 1
        if s == FLAT or s == HEEL:
            lo, hi = min(lo, pts[heel, 0]), max(hi, pts[heel, 0])
        if s == FLAT or s == TOE:
            lo, hi = min(lo, pts[toe, 0]), max(hi, pts[toe, 0])
        if s == FLAT:
            n_flat += 1
            n_points += 2
        elif s != AIR:
            n_points += 1
        anchor = toe if s == TOE else heel
        if s != AIR:
            for r in range(3 if s == FLAT else 2):
                E[ne] = Jp[anchor, r]
                e[ne] = -bp[anchor, r] - params[P_DAMP] * (Jp[anchor, r] @ qd)
                ne += 1
        if foot == swing:  # task-space objective: heel point (x, z) and foot pitch toward the swing plan
            pitch = q[2] + q[leg_dofs[foot, 0]] + q[leg_dofs[foot, 1]] + q[leg_dofs[foot, 2]]
            own = swing_target_row[S_SWING_GAINS] > 0.0  # this swing's own gains (a planned step's)
            w_sw = swing_target_row[S_SWING_GAINS] if own else params[P_SW]
            k_sw = swing_target_row[S_SWING_GAINS + 1] if own else params[P_SK]
            d_sw = swing_target_row[S_SWING_GAINS + 2] if own else params[P_SD]
            for r in range(3):
                jr = Jp[heel, r]
                pos = pts[heel, 0] if r == 0 else (pts[heel, 2] if r == 1 else pitch)
                target = (swing_target_row[6 + r] + k_sw * (swing_target_row[r] - pos)
                          + d_sw * (swing_target_row[3 + r] - jr @ qd) - bp[heel, r])
                Q += w_sw * np.outer(jr, jr)
                g += w_sw * target * jr
        elif s != FLAT:
            jp = Jp[heel, 2]
            pitch = q[2] + q[leg_dofs[foot, 0]] + q[leg_dofs[foot, 1]] + q[leg_dofs[foot, 2]]
            if swing_target_row[S_LANDING] == foot + 1:  # landed heel first: the toe comes down to the floor
                aim, w_r = swing_target_row[S_LANDING + 1], swing_target_row[S_LANDING + 2]
                k_r, d_r = swing_target_row[S_LANDING + 3], swing_target_row[S_LANDING + 4]
            else:
                aim, w_r, k_r, d_r = 0.0, params[P_RW], params[P_RK], params[P_RD]
            target = -k_r * (pitch - aim) - d_r * (jp @ qd) - bp[heel, 2]
            Q += w_r * np.outer(jp, jp)
            g += w_r * target * jp
    return E, e, ne, lo, hi, n_flat, n_points


@njit(cache=True, nogil=True)
def _point_floor(fmin, n_flat, n_points, length, low_load):
    """How far the CoP rows keep the CoP from the support's ends so that every loaded heel/toe point carries its
    floor: (edge, band) with (p - lo) F_z >= edge + band F_z. Normally the floor is ``fmin`` per point (edge): a
    point planned below ~35 N goes slack for a physics step now and then (the plan is followed with a lag on a
    soft contact), and the CoP of the rest jumps to an end (measured: docs/controller.md). That floor closes the
    band at the support centre as F_z falls to n_points x fmin; so when the load is too low to give every point
    ``fmin`` and keep half the foot (``low_load``: F_z < 2 n_points fmin), the floor is half an equal share per
    point instead (band): the plan's CoP keeps the middle half of the feet at any load, where the controller can
    still place it."""
    if low_load:
        return 0.0, n_flat * length / (2.0 * max(n_points, 1))
    return fmin * n_flat * length, 0.0


@njit(cache=True, nogil=True)
def _ground_rows(A, a_g, pts, com, mg, params, support, nrow, E, e, ne, low_load=False):
    """The ground's rows on the wrench w = A qdd + a (F_x = w0, F_z = w1 + m g, Hdot = w2): unilateral F_z,
    two friction rows and two CoP rows (C, c, the first N_INEQ of ``nrow`` rows; the rest are filled by
    :func:`_torque_rows` and :func:`_stop_rows`) with which are on; a rolling foot's CoP equality and an airborne
    body's zero wrench go into (E, e). ``support``: (lo, hi, n_flat, n_points). Returns (C, c, c_on, ne, arm)."""
    lo, hi, n_flat, n_points = support
    nv = A.shape[1]
    grounded = n_points > 0
    rolling = grounded and n_flat == 0
    zc = (pts[0, 2] + pts[1, 2] + pts[2, 2] + pts[3, 2]) / 4.0
    arm = zc - com[2]
    mu, fmin = params[P_MU], params[P_FMIN]
    edge, band = _point_floor(fmin, n_flat, n_points, hi - lo, low_load)
    R = np.zeros((N_INEQ, 3))
    r0 = np.zeros(N_INEQ)
    R[0, 1] = 1.0
    r0[0] = mg - params[P_FZMIN] * n_points
    R[1, 0], R[1, 1], r0[1] = -1.0, mu, mu * mg
    R[2, 0], R[2, 1], r0[2] = 1.0, mu, mu * mg
    R[3, 0], R[3, 1], R[3, 2], r0[3] = arm, com[0] - lo - band, -1.0, (com[0] - lo - band) * mg - edge
    R[4, 0], R[4, 1], R[4, 2], r0[4] = -arm, hi - com[0] - band, 1.0, (hi - com[0] - band) * mg - edge
    C = np.zeros((nrow, nv))
    c = np.empty(nrow)
    C[:N_INEQ] = R @ A
    c[:N_INEQ] = R @ a_g + r0
    c_on = np.zeros(nrow, np.bool_)
    if grounded:
        c_on[:3] = True
        if rolling:  # the CoP is exactly at the rolling edge
            E[ne] = C[3]
            e[ne] = -c[3]
            ne += 1
        else:
            c_on[3:N_INEQ] = True
    else:  # airborne: no ground force at all
        for r in range(3):
            E[ne] = A[r]
            e[ne] = -a_g[r] - (mg if r == 1 else 0.0)
            ne += 1
    return C, c, c_on, ne, arm


@njit(cache=True, nogil=True)
def _torque_map(dyn, actuated, nu_rows, grounded, A, a_g, mg, com, arm, pts, Jp, loaded):
    """The torques are affine in the plan, tau = T qdd + t0 (inverse dynamics with the plan's ground forces
    split over the loaded points): T's rows for the actuated dofs (``nu_rows``: 0 without the limits in the
    plan) and t0 (every dof) at qdd = 0. ``dyn``: (M, h); ``loaded``: :func:`_loaded_points`."""
    M, h = dyn
    carries, count, mean, spread = loaded
    nv = h.size
    Tm = np.empty((nu_rows, nv))
    for u in range(nu_rows):
        Tm[u] = M[actuated[u]]
    t0 = h.copy()
    if grounded and nu_rows > 0:
        # F_z share of point p: fz / count + (x_p - mean) (cop fz - mean fz) / spread, and cop fz =
        # com_x fz + arm F_x - Hdot is linear in w; F_x is split equally (exact for feet side by side)
        fx_share = A[0] / count
        for p in range(4):
            if carries[p]:
                lever = (pts[p, 0] - mean) / spread if spread > 1e-12 else 0.0
                dz = A[1] / count + lever * ((com[0] - mean) * A[1] + arm * A[0] - A[2])
                z0 = (a_g[1] + mg) / count + lever * ((com[0] - mean) * (a_g[1] + mg) + arm * a_g[0] - a_g[2])
                for u in range(nu_rows):  # the same operations as Tm -= outer(Jx, fx_share) + outer(Jz, dz)
                    jx, jz = Jp[p, 0, actuated[u]], Jp[p, 1, actuated[u]]
                    for j in range(nv):
                        Tm[u, j] -= jx * fx_share[j] + jz * dz[j]
                t0 -= Jp[p, 0] * (a_g[0] / count) + Jp[p, 1] * z0
    return Tm, t0


@njit(cache=True, nogil=True)
def _load_forces(frame, qd, chain, ext_bodies, ext_p_row, com, fex, fez):
    """A held load's generalized force, per body of ``ext_bodies`` (the load shared equally); no rows when
    there is no load. ``frame``: the row's (cdof, cdof_dot, cvel)."""
    cdof_r, cdof_dot_r, cvel_r = frame
    loaded = fex != 0.0 or fez != 0.0
    load_gen = np.zeros((ext_bodies.size if loaded else 0, qd.size))
    for eb in range(load_gen.shape[0]):
        Je, _ = point_frame(cdof_r, cdof_dot_r, cvel_r, qd, chain[ext_bodies[eb]], ext_bodies[eb], ext_p_row, com)
        load_gen[eb] = Je[0] * (fex / ext_bodies.size) + Je[1] * (fez / ext_bodies.size)
    return load_gen


@njit(cache=True, nogil=True)
def _field_load(frame, qd, chain, field_f, field_p, com):
    """A force field on every body (``cmrt.body.surface``: what the support's tilt and motion add to gravity in
    its frame): its wrench about the CoM (F_x, F_z, H_y rate) and its generalized force (1, nv); no rows when
    ``field_f`` (nb, 3: f_x, f_z at the body's CoM ``field_p``, torque about y) has no bodies."""
    cdof_r, cdof_dot_r, cvel_r = frame
    nbf = field_f.shape[0]
    wrench = np.zeros(3)
    gen = np.zeros((1 if nbf > 0 else 0, qd.size))
    for b in range(nbf):
        fx, fz, ty = field_f[b, 0], field_f[b, 1], field_f[b, 2]
        if fx == 0.0 and fz == 0.0 and ty == 0.0:
            continue
        J, _ = point_frame(cdof_r, cdof_dot_r, cvel_r, qd, chain[b], b, field_p[b], com)
        gen[0] += J[0] * fx + J[1] * fz + J[2] * ty
        wrench[0] += fx
        wrench[1] += fz
        wrench[2] += (field_p[b, 2] - com[2]) * fx - (field_p[b, 0] - com[0]) * fz + ty
    return wrench, gen


@njit(cache=True, nogil=True)
def _ground_bias(a, frame, qd, chain, com, ext_f_row, ext_p_row, field_f_row, field_p_row):
    """What the ground must give of the momentum rate at qdd = 0, a_g, and the support's field (its wrench and
    generalized force, :func:`_field_load`).

    A known external force on the hands (a held load, ``ext_f_row`` (x, z) N at ``ext_p_row``): the ground gives
    the momentum rate less it, a_g = a - (f_x, f_z, r x f). A force field on every body (a tilted or moving
    support, simulated in its own frame) is known to the plan the same way, and the torques take its generalized
    force out. No field bodies (a still, level floor): nothing changes, bit for bit."""
    a_g = a.copy()
    fex, fez = ext_f_row[0], ext_f_row[1]
    a_g[0] -= fex
    a_g[1] -= fez
    a_g[2] -= (ext_p_row[2] - com[2]) * fex - (ext_p_row[0] - com[0]) * fez
    field_w, field_gen = _field_load(frame, qd, chain, field_f_row, field_p_row, com)
    if field_gen.shape[0] > 0:
        a_g[0] -= field_w[0]
        a_g[1] -= field_w[1]
        a_g[2] -= field_w[2]
    return a_g, field_w, field_gen


@njit(cache=True, nogil=True)
def _torque_rows(C, c, c_on, torque, actuated, limits):
    """The motors' limits as rows of the QP (in place, after the ground's N_INEQ rows): |T qdd + t0| <= the torque
    limit. ``torque``: (Tm, t0)."""
    Tm, t0 = torque
    for u in range(actuated.size):
        ju = actuated[u]
        lim = limits[u, 0]
        C[N_INEQ + 2 * u] = -Tm[u]
        c[N_INEQ + 2 * u] = lim - t0[ju]
        C[N_INEQ + 2 * u + 1] = Tm[u]
        c[N_INEQ + 2 * u + 1] = lim + t0[ju]
        c_on[N_INEQ + 2 * u] = c_on[N_INEQ + 2 * u + 1] = True


@njit(cache=True, nogil=True)
def _stop_rows(C, c, c_on, q, qd, actuated, limits, params):
    """The joint stops as rows of the QP (in place, after the torque rows): a joint may approach its stop (less a
    margin) no faster than a critically damped spring would, qdd >= -k (q - lo) - d qd: the plan never leans on a
    stop, whose force it does not model (a standing knee on its 0 rad stop carried up to 47 N m that way)."""
    nu = actuated.size
    kj, dj = params[P_JK], params[P_JD]
    for u in range(nu):
        ju = actuated[u]
        r = N_INEQ + 2 * nu + 2 * u
        C[r, ju] = 1.0
        c[r] = kj * (q[ju] - limits[u, 1]) + dj * qd[ju]
        C[r + 1, ju] = -1.0
        c[r + 1] = -kj * (q[ju] - limits[u, 2]) - dj * qd[ju]
        c_on[r] = c_on[r + 1] = True


@njit(cache=True, nogil=True)
def _inverse_dynamics(A, qdd, a_g, mg, com, arm, dyn, load_gen, pts, Jp, loaded, fmin, motors, in_plan, tau_row):
    """The torques of the solved plan (into ``tau_row``): inverse dynamics with the plan's ground forces split
    over the loaded points (bounded shares in a split stance) and the held load taken out, each clipped at its
    limit (within LIMIT_SLACK with the limits in the plan: rounding only). Returns (F_x, F_z, CoP x, saturated).
    ``dyn``: (M, h); ``loaded``: :func:`_loaded_points`; ``motors``: (actuated, limits)."""
    M, h = dyn
    carries, count, mean, spread = loaded
    actuated, limits = motors
    w = A @ qdd + a_g
    fx, fz = w[0], w[1] + mg
    cop = com[0] + (arm * fx - w[2]) / fz if fz > 1e-9 else com[0]
    gen = M @ qdd + h
    for eb in range(load_gen.shape[0]):
        gen -= load_gen[eb]
    split = ((carries[0] or carries[1]) and (carries[2] or carries[3])
             and abs(pts[0, 0] - pts[2, 0]) > SPLIT_STANCE_M and fz > 1e-9)
    if split:
        shares = bounded_shares(pts[:, 0], carries, cop, min(fmin / fz, 0.5 / count))
    for p in range(4):
        if carries[p]:
            if split:
                share = shares[p]
            else:
                share = 1.0 / count
                if spread > 1e-12:
                    share += (pts[p, 0] - mean) * (cop - mean) / spread
            gen -= Jp[p, 0] * (share * fx) + Jp[p, 1] * (share * fz)
    saturated = 0.0  # clipped at a motor limit (with the limits in the plan: the QP found no plan within them)
    for u in range(actuated.size):
        t = gen[actuated[u]]
        lim = limits[u, 0]
        if abs(t) > (lim * (1.0 + LIMIT_SLACK) if in_plan else lim):
            saturated = 1.0
        tau_row[u] = min(max(t, -lim), lim)
    return fx, fz, cop, saturated


@njit(cache=True, nogil=True)
def _plan(qp, params, passes, active, in_plan, body, motors):
    """The QP's plan (``solve_qp``; ``active`` in and out). With the motors' limits and the joint stops in the plan,
    the torque rows (the costly part: the torque map) are built only when they may bind: if none was active at the
    last control step, the QP is first solved with the ground's and the joint stops' rows alone and that plan kept
    if it keeps every torque row clear by ``LIMIT_CLEARANCE`` - it is then the whole QP's optimum (a convex QP whose
    relaxed optimum is feasible), found from the same final set of rows in the same order, so bit for bit the same
    plan. Otherwise the torque rows are built and the whole QP is solved. Most steps need none (``cmrt bench``).
    ``qp``: (Q, g, E, e, C, c, c_on) with the ground's rows filled; ``body``: (q, qd, dyn, loaded, load_gen,
    (A, a_g, mg, com, arm, pts, Jp, n_points)); ``motors``: (actuated, limits)."""
    Q, g, E, e, C, c, c_on = qp
    if not in_plan:
        return solve_qp(Q, g, E, e, C, c, c_on, params[P_DUALREG], passes, active)
    q, qd, dyn, loaded, load_gen, geo = body
    actuated, limits = motors
    A, a_g, mg, com, arm, pts, Jp, n_points = geo
    nu = actuated.size
    _stop_rows(C, c, c_on, q, qd, actuated, limits, params)
    relaxed = True
    for k in range(N_INEQ, N_INEQ + 2 * nu):
        relaxed = relaxed and not active[k]
    if relaxed:
        trial = active.copy()
        x = solve_qp(Q, g, E, e, C, c, c_on, params[P_DUALREG], passes, trial)
        if _clear_of_limits(x, dyn, loaded, load_gen, geo, motors):
            active[:] = trial
            return x
    Tm, t0 = _torque_map(dyn, actuated, nu, n_points > 0, A, a_g, mg, com, arm, pts, Jp, loaded)
    for eb in range(load_gen.shape[0]):
        t0 -= load_gen[eb]
    _torque_rows(C, c, c_on, (Tm, t0), actuated, limits)
    return solve_qp(Q, g, E, e, C, c, c_on, params[P_DUALREG], passes, active)


@njit(cache=True, nogil=True)
def _clear_of_limits(x, dyn, loaded, load_gen, geo, motors):
    """Whether the plan ``x`` keeps every torque row of :func:`_torque_rows` clear by ``LIMIT_CLEARANCE`` of its
    limit: each motor's torque - the same affine map, tau = M x + h - the held load - J' f with the plan's ground
    force split as :func:`_torque_map` splits it - within its limit."""
    M, h = dyn
    carries, count, mean, spread = loaded
    actuated, limits = motors
    A, a_g, mg, com, arm, pts, Jp, n_points = geo
    gen = M @ x + h
    for eb in range(load_gen.shape[0]):
        gen -= load_gen[eb]
    if n_points > 0:
        w = A @ x + a_g
        fz = w[1] + mg
        moment = (com[0] - mean) * fz + arm * w[0] - w[2]  # (cop - mean) fz, linear in the plan
        for p in range(4):
            if carries[p]:
                lever = (pts[p, 0] - mean) / spread if spread > 1e-12 else 0.0
                gen -= Jp[p, 0] * (w[0] / count) + Jp[p, 1] * (fz / count + lever * moment)
    for u in range(actuated.size):
        lim = limits[u, 0]
        if abs(gen[actuated[u]]) > lim - LIMIT_CLEARANCE * lim:
            return False
    return True


# control_step's arguments, grouped: ``fields`` (cdof, cdof_dot, cvel, cinert, qpos, qvel, M_sparse, qfrc_bias,
# qfrc_passive, com_all, geom_xpos) are the batch's bound MuJoCo fields, of which simulation ``i`` reads row
# ``rows[i]`` (the compiled scoring loop passes the whole batch and its active rows: no copies when rows drop out)
# - only the humanoid's leading slices are read; ``model`` (chain, m_rows, m_cols, points, point_bodies, leg_dofs,
# actuated, limits, w2, params) the controller's constants (w2 (2, nv): the squared tracking weights standing and
# walking); ``refs`` (q_ref, qd_ref, qdd_ref, com_ref_x,
# com_ref_vel_x, cop_des_x) per-simulation targets (references (n, nv): an ensemble's members may play the motion
# at different speeds); ``support`` (contact, mass_all, swing_foot, swing_target): ``mass_all`` (n,) is each
# character's mass with what it carries (a caught ball's mass moves into the forearms); ``warm`` (warm_in,
# warm_out); ``load`` (ext_f, ext_p, ext_bodies); ``out`` (tau_out, info_out). See controller.py for the
# formulation.
@njit(cache=True, nogil=True)
def control_step(rows, fields, model, refs, support, warm, load, out):
    """Torques (tau_out, (n, nu)) for n simulations; info_out (n, N_INFO) gets the plan's summary (the
    arguments' groups: the comment above).

    A swinging foot (``swing_foot[i]`` >= 0) has no support rows and carries no load; its heel point and
    pitch track ``swing_target[i]`` as a weighted objective, and its leg's joint tracking is weakened.
    ``warm_in`` / ``warm_out`` (rows, n_rows(nu)) bool, read / written at row ``rows[i]``: the QP's active set
    to start from (the row's previous control step's) and the one it ended on. The caller keeps ``warm_out``
    as the next step's ``warm_in`` only once the whole call has succeeded (a singular plan raises).
    ``ext_f[i]`` (x, z) N acting at ``ext_p[i]`` (world, (x, y, z)) on the bodies ``ext_bodies`` (shared equally):
    a load the character holds (``Prop.hand_load``), known to the plan - the ground gives the momentum rate less
    it, and the torques take its generalized force out. Zero: the clip is computed as without it, bit for bit."""
    cdof, cdof_dot, cvel, cinert, qpos, qvel, M_sparse, qfrc_bias, qfrc_passive, com_all, geom_xpos = fields
    chain, m_rows, m_cols, points, point_bodies, leg_dofs, actuated, limits, w2, params = model
    q_ref, qd_ref, qdd_ref, com_ref_x, com_ref_vel_x, cop_des_x = refs
    contact, mass_all, swing_foot, swing_target = support
    (warm_in, warm_out), (ext_f, ext_p, ext_bodies, field_f, field_p), (tau_out, info_out) = warm, load, out
    n = rows.shape[0]
    nb, nv = chain.shape
    grav = params[P_G]
    radius = params[P_RADIUS]
    nu = actuated.size
    in_plan = params[P_LIMITS] > 0.0  # off: motor limits clipped after the solve (the v0.2 controller, bit for bit)
    nrow = N_INEQ + 4 * nu if in_plan else N_INEQ  # the QP's inequality rows; the warm arrays are n_rows(nu) wide
    for i in range(n):
        row = rows[i]
        mass = mass_all[i]
        mg = mass * grav
        qd = qvel[row, :nv].copy()
        q = qpos[row, :nv]
        com = com_all[row, 1]
        frame = (cdof[row], cdof_dot[row], cvel[row])
        A, a = centroidal(cdof[row], cdof_dot[row], cvel[row], cinert[row], qd, chain)
        fex, fez = ext_f[i, 0], ext_f[i, 1]
        a_g, field_w, field_gen = _ground_bias(a, frame, qd, chain, com, ext_f[i], ext_p[i], field_f[i], field_p[i])
        pts, Jp, bp = _contact_points(frame, qd, chain, points, point_bodies, geom_xpos[row], radius, com)
        swing = int(swing_foot[i])
        state = _foot_states(contact[i], swing)
        # the objective, then the support rows (a foot that is not flat gets a soft return-to-flat pitch target)
        Q, g = _objective(A, a, qd, q, com, mass, mg, params, w2, leg_dofs, swing, i,
                          (q_ref, qd_ref, qdd_ref, com_ref_x, com_ref_vel_x, cop_des_x, swing_target),
                          field_w if field_gen.shape[0] > 0 else field_w[:0])
        E, e, ne, lo, hi, n_flat, n_points = _support_rows(state, (pts, Jp, bp), qd, q, params, leg_dofs, swing,
                                                          swing_target[i], Q, g)
        support_now, ne_support = (lo, hi, n_flat, n_points), ne
        C, c, c_on, ne, arm = _ground_rows(A, a_g, pts, com, mg, params, support_now, nrow, E, e, ne_support)

        # the torques are affine in the plan, tau = T qdd + t0: the motors' limits are rows of the QP, so the
        # plan is one the motors can carry out - nothing is clipped after the solve (built only when they may bind)
        loaded = _loaded_points(state, pts)
        dyn = _dense_dynamics(row, M_sparse, m_rows, m_cols, qfrc_bias, qfrc_passive, nv)
        load_gen = _load_forces(frame, qd, chain, ext_bodies, ext_p[i], com, fex, fez)
        if field_gen.shape[0] > 0:
            load_gen = np.concatenate((load_gen, field_gen))
        active = warm_in[row, :nrow].copy() if params[P_WARM] > 0.0 else np.zeros(nrow, np.bool_)
        passes = MAX_PASSES_LIMITS if in_plan else MAX_PASSES
        body = (q, qd, dyn, loaded, load_gen, (A, a_g, mg, com, arm, pts, Jp, n_points))
        qdd = _plan((Q, g, E[:ne], e[:ne], C, c, c_on), params, passes, active, in_plan, body,
                    (actuated, limits))
        if n_flat > 0 and A[1] @ qdd + a_g[1] + mg < 2.0 * n_points * params[P_FMIN]:  # a low load: the floor per
            C, c, c_on, ne, arm = _ground_rows(A, a_g, pts, com, mg, params, support_now, nrow, E, e, ne_support,
                                               True)  # point becomes half an equal share (_point_floor), re-planned
            qdd = _plan((Q, g, E[:ne], e[:ne], C, c, c_on), params, passes, active, in_plan, body,
                        (actuated, limits))
        warm_out[row, :nrow] = active
        warm_out[row, nrow:] = False

        fx, fz, cop, saturated = _inverse_dynamics(A, qdd, a_g, mg, com, arm, dyn, load_gen, pts, Jp, loaded,
                                                   params[P_FMIN], (actuated, limits), in_plan, tau_out[i])
        info_out[i, 0], info_out[i, 1], info_out[i, 2] = fx, fz, cop
        info_out[i, 3], info_out[i, 4], info_out[i, 5] = state[0], state[1], saturated
