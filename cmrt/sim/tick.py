"""One control step of the scoring loop, compiled: read the state, record, control, judge balance.

``simulate_batch`` spends most of its time outside ``Batch.step`` in its control step: ~60
numpy calls and three compiled calls per step, a few microseconds each, ~400 times per clip,
whatever the batch size (docs/performance.md has the profile). :func:`control_tick` does the
same work in one compiled call per step for a scoring run in the ``center`` reference mode with
feet planted - what an optimization evaluates. Traces, the ``yu`` reference and stepping keep the
Python loop (their extra work is per step and per row, but they are not the hot path).

Everything is the same IEEE arithmetic in the same order as the numpy code it stands for,
so trajectories are bit for bit those of the Python path (tests/sim/test_tick.py compares the two
on every task):

* :func:`geometry` is the ``_Geometry``/``_in_contact``/``_ground_support`` numpy code (NaNs
  propagate as numpy's min/max let them);
* :func:`linear_momentum` is ``PlanarKinematics.linear_momentum``: numpy sums the bodies of a
  row pairwise, eight partial sums first (``pairwise_sum`` in numpy's ``loops_utils``), and so
  does it;
* the controller is ``cmrt.control.kernel.control_step`` itself, the monitor
  ``cmrt.sim.balance._first_failed`` itself.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
from numba import njit

from cmrt.control import kernel
from cmrt.control.kernel import N_INFO, N_SWING, control_step
from cmrt.sim import balance
from cmrt.sim.balance import _first_failed


def drop_stale_cache(here: Path = Path(__file__)) -> bool:
    """Drop this module's numba cache when a module it compiles in has changed; True if it did.

    numba keys a cached function by its own source file only, and ``control_tick`` compiles
    ``kernel.control_step`` and ``balance._first_failed`` into itself: after an edit of kernel.py alone the
    cached tick would go on running the old controller while the Python path runs the new one (measured:
    trajectories differed from the first control step). A stamp of those sources next to the cache says
    which versions the cache was built from. Best effort: an unwritable cache directory is numba's
    user-wide one, which this does not touch."""
    stamp = hashlib.sha256(b"".join(Path(m.__file__).read_bytes() for m in (kernel, balance))).hexdigest()
    cache = here.parent / "__pycache__"
    marker = cache / f"{here.stem}.inlined.sha256"
    try:
        if marker.read_text() == stamp:
            return False
    except OSError:
        pass
    try:
        for f in list(cache.glob(f"{here.stem}.*.nbi")) + list(cache.glob(f"{here.stem}.*.nbc")):
            f.unlink()
        cache.mkdir(exist_ok=True)
        marker.write_text(stamp)
    except OSError:
        return False
    return True


drop_stale_cache()  # before the first call loads the cache


@njit(cache=True, nogil=True)
def geometry(rows, fields, consts, out):
    """What a control step reads of the batch's geometry, for every row, in one compiled pass instead of
    ~30 numpy calls (each a few microseconds, ~400 times per clip): heel/toe x and their span, which points
    touch the floor, foot pitch, the fastest actuated joint, the lowest body point and the span of the feet
    on the ground. The same IEEE operations in the same order as the numpy code it replaces
    (``_Geometry``, ``_in_contact``, ``_ground_support``), NaNs propagated as numpy's min/max do, so
    results are bit for bit those of before. Output row ``i`` is batch row ``rows[i]``.

    ``fields``: (geom_xpos, geom_xmat, qpos, qvel), the batch's; ``consts``: (points, body_geoms, half, radius,
    leg_dofs, root_pitch, act, point_radius, contact_height); ``out``, rows ``rows``: (point_x, lo, hi, contact,
    roll, jspeed, lowest, grounded, c_lo, c_hi)."""
    geom_xpos, geom_xmat, qpos, qvel = fields
    points, body_geoms, half, radius, leg_dofs, root_pitch, act, point_radius, contact_height = consts
    point_x, lo, hi, contact, roll, jspeed, lowest, grounded, c_lo, c_hi = out
    n = point_x.shape[0]
    npt = points.shape[0]
    for i in range(n):
        row = rows[i]
        for p in range(npt):
            point_x[i, p] = geom_xpos[row, points[p], 0]
            contact[i, p] = geom_xpos[row, points[p], 2] - point_radius < contact_height
        a, b = point_x[i, 0], point_x[i, 0]
        for p in range(1, npt):
            x = point_x[i, p]
            if a == a:
                a = x if (x != x or x < a) else a
            if b == b:
                b = x if (x != x or x > b) else b
        lo[i], hi[i] = a, b
        for f in range(2):
            roll[i, f] = qpos[row, root_pitch] + ((qpos[row, leg_dofs[f, 0]] + qpos[row, leg_dofs[f, 1]])
                                                + qpos[row, leg_dofs[f, 2]])
        m = abs(qvel[row, act[0]])
        for j in range(1, act.shape[0]):
            v = abs(qvel[row, act[j]])
            if m == m:
                m = v if (v != v or v > m) else m
        jspeed[i] = m
        z = geom_xpos[row, body_geoms[0], 2] - abs(geom_xmat[row, body_geoms[0], 8]) * half[0] - radius[0]
        for g in range(1, body_geoms.shape[0]):
            v = geom_xpos[row, body_geoms[g], 2] - abs(geom_xmat[row, body_geoms[g], 8]) * half[g] - radius[g]
            if z == z:
                z = v if (v != v or v < z) else z
        lowest[i] = z
        down = False
        a, b = np.inf, -np.inf
        for p in range(npt):
            foot = p // 2
            if contact[i, 2 * foot] or contact[i, 2 * foot + 1]:
                down = True
                x = point_x[i, p]
                if a == a:
                    a = x if (x != x or x < a) else a
                if b == b:
                    b = x if (x != x or x > b) else b
        grounded[i] = down
        c_lo[i], c_hi[i] = (a, b) if down else (np.nan, np.nan)


@njit(cache=True, nogil=True)
def _pairwise_sum(x):
    """numpy's sum of a short contiguous row (``pairwise_sum`` for n <= 128): under 8 terms one by one from
    -0.0, else eight interleaved partial sums combined as a tree, then the remainder one by one (checked
    bit for bit against ``np.sum(axis=1)`` in tests/sim/test_tick.py)."""
    n = x.shape[0]
    if n < 8:
        s = -0.0
        for i in range(n):
            s += x[i]
        return s
    r0, r1, r2, r3, r4, r5, r6, r7 = x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7]
    m = n - n % 8
    for i in range(8, m, 8):
        r0 += x[i]
        r1 += x[i + 1]
        r2 += x[i + 2]
        r3 += x[i + 3]
        r4 += x[i + 4]
        r5 += x[i + 5]
        r6 += x[i + 6]
        r7 += x[i + 7]
    s = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    for i in range(m, n):
        s += x[i]
    return s


@njit(cache=True, nogil=True)
def linear_momentum(rows, cinert, cvel, nb, out):
    """``PlanarKinematics.linear_momentum`` of batch rows ``rows`` into ``out`` (n, 2): L_x, L_z over the
    first ``nb`` bodies, summed as numpy sums them."""
    n = rows.shape[0]
    terms = np.empty(nb)
    for i in range(n):
        row = rows[i]
        for b in range(nb):
            terms[b] = cinert[row, b, 8] * cvel[row, b, 1] + cinert[row, b, 9] * cvel[row, b, 3]
        out[i, 0] = _pairwise_sum(terms)
        for b in range(nb):
            terms[b] = cinert[row, b, 9] * cvel[row, b, 5] - cinert[row, b, 6] * cvel[row, b, 1]
        out[i, 1] = _pairwise_sum(terms)


# The arguments, grouped (``simulate._CompiledTick`` binds all but ``k``, ``ids``, ``now`` and ``out``): ``clock``
# (dt, control_dt, nb, mass_kg); ``fields``, the batch's bound fields, every row (simulation ``s`` is batch row
# ``s``): (geom_xpos, geom_xmat, qpos, qvel, cdof, cdof_dot, cvel, cinert, M, qfrc_bias, qfrc_passive, subtree_com,
# time_s); ``consts``, geometry and monitor constants: (points, body_geoms, half, radius, leg_dofs, root_pitch, act,
# point_radius, contact_height, com_height_m, airborne_s, roll_rad, capture_margin_m); ``controller``'s constants:
# (chain, m_rows, m_cols, point_bodies, actuated, torque_limits, w2, params); ``drive``, what drives each row -
# references (variants, steps, nv), each row's variant, the CMRT: (q_ref, qd_ref, qdd_ref, variant, disp_m,
# disp_vel_m_s); ``lean``, whether to look for leaning on a prop (last step's force > leaning_n): (lean_check,
# prop_force, leaning_n); ``state``, monitor state and records, (n_all, ...): (airborne_for_s, fall_code, rec_sc,
# rec_lo, rec_hi, rec_qpos, rec_com, rec_jspeed, rec_cref, rec_plan); ``now``, the mass the character carries, the held
# references and the torques: (carried_kg, com_ref_now, cop_ref_now, ctrl_all); ``delay``, the balance feedback's
# delay (steps) and the CoM velocity at past control steps (n_all, steps): (delay_steps, fb_vel); ``warm_sets``, the
# QPs' active sets (n_all, rows), kept from the last control step, and this step's first: (warm, warm_out);
# ``load``, a held load's pull on the hands, rows ``ids``: (ext_f, ext_p, ext_bodies) - force (n, 2), point (n, 3),
# the bodies sharing it; ``held``, a mass the hands hold and the bodies do not carry, rows ``ids`` (``Prop.held_mass``:
# the balance monitor adds it to the CoM; the controller balances ``share`` of it): (mass (n,), x/z (n, 2),
# x velocity (n,), share (n,)); ``out``, rows ``ids``:
# (point_x, momentum, new).
@njit(cache=True, nogil=True)
def _counterweighted(com_ref, held, r, mass_kg):
    """The CoM target with the body and the balanced share of row ``r``'s held mass over it together (``held``: see
    control_tick; ``simulate._balancing_held``'s operations): c_r - w m (x_held - c_r) / M."""
    share = held[3][r]
    if share > 0.0:
        return com_ref - share * held[0][r] * (held[1][r, 0] - com_ref) / mass_kg
    return com_ref


@njit(cache=True, nogil=True)
def control_tick(k, ids, clock, fields, consts, controller, drive, lean, state, now, delay, warm_sets, load, held, out):
    """Control step ``k`` of a scoring run, rows ``ids`` (center reference, feet planted, nobody fallen),
    in the Python loop's order: geometry, records, CoM velocity, targets ``c_r = s + d(t)``, ``p_r = s``,
    torques (into ``ctrl_all``; the caller copies them into the batch) and the balance monitor.

    ``new`` gets the rows that fell now, ``momentum`` the rows' (L_x, L_z), ``point_x`` their heel/toe x
    (the step's CoP sample needs them). Returns how many rows fell now, or -1, having done nothing, if a
    row had fallen before (protective mode is the Python path's). A singular plan raises ``LinAlgError``
    before the monitor has changed anything: the caller redoes the step on the Python path, which finds
    the row. Its arguments, grouped: the comment above."""
    dt, control_dt, nb, mass_kg = clock
    (geom_xpos, geom_xmat, qpos, qvel, cdof, cdof_dot, cvel, cinert, M, qfrc_bias, qfrc_passive, subtree_com,
     time_s) = fields
    (points, body_geoms, half, radius, leg_dofs, root_pitch, act, point_radius, contact_height, com_height_m,
     airborne_s, roll_rad, capture_margin_m) = consts
    chain, m_rows, m_cols, point_bodies, actuated, torque_limits, w2, params = controller
    q_ref, qd_ref, qdd_ref, variant, disp_m, disp_vel_m_s = drive
    airborne_for_s, fall_code, rec_sc, rec_lo, rec_hi, rec_qpos, rec_com, rec_jspeed, rec_cref, rec_plan = state
    carried_kg, com_ref_now, cop_ref_now, ctrl_all = now
    delay_steps, fb_vel = delay
    (warm, warm_out), (ext_f, ext_p, ext_bodies), (point_x, momentum, new) = warm_sets, load, out
    n = ids.shape[0]
    for r in range(n):
        if fall_code[ids[r]] != 0:
            return -1
    npt = points.shape[0]
    nu = actuated.shape[0]
    nv = chain.shape[1]
    lo, hi, jspeed, lowest, c_lo, c_hi = (np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n),
                                          np.empty(n))
    contact = np.empty((n, npt), np.bool_)
    grounded = np.empty(n, np.bool_)
    roll = np.empty((n, 2))
    geometry(ids, (geom_xpos, geom_xmat, qpos, qvel),
             (points, body_geoms, half, radius, leg_dofs, root_pitch, act, point_radius, contact_height),
             (point_x, lo, hi, contact, roll, jspeed, lowest, grounded, c_lo, c_hi))
    linear_momentum(ids, cinert, cvel, nb, momentum)
    vel_x = np.empty(n)
    mass = np.empty(n)
    com_ref, com_ref_vel, cop_ref = np.empty(n), np.empty(n), np.empty(n)
    qr, qdr, qddr = np.empty((n, nv)), np.empty((n, nv)), np.empty((n, nv))
    nq_rec = rec_qpos.shape[2]
    for r in range(n):
        s = ids[r]
        center = 0.5 * (lo[r] + hi[r])
        rec_sc[s, k], rec_lo[s, k], rec_hi[s, k] = center, lo[r], hi[r]
        for j in range(nq_rec):
            rec_qpos[s, k, j] = qpos[s, j]
        rec_com[s, k, 0], rec_com[s, k, 1] = subtree_com[s, 1, 0], subtree_com[s, 1, 2]
        mass[r] = mass_kg + carried_kg[s]
        vel_x[r] = momentum[r, 0] / mass[r]
        rec_jspeed[s, k] = jspeed[r]
        com_ref[r] = _counterweighted(center + disp_m[s, k], held, r, mass[r])
        com_ref_vel[r] = disp_vel_m_s[s, k]
        cop_ref[r] = center
        com_ref_now[s], cop_ref_now[s] = com_ref[r], cop_ref[r]
        rec_cref[s, k] = com_ref[r]
        fb_vel[s, k] = vel_x[r]
        if delay_steps > 0:  # the feedback sees the CoM of delay_steps ago (simulate._delayed, the same operations)
            kd = k - delay_steps if k >= delay_steps else 0
            com_ref[r] += subtree_com[s, 1, 0] - rec_com[s, kd, 0]
            com_ref_vel[r] += vel_x[r] - fb_vel[s, kd]
        v = variant[s]
        for j in range(nv):
            qr[r, j], qdr[r, j], qddr[r, j] = q_ref[v, k, j], qd_ref[v, k, j], qdd_ref[v, k, j]

    tau = np.empty((n, nu))
    info = np.empty((n, N_INFO))
    control_step(ids, (cdof, cdof_dot, cvel, cinert, qpos, qvel, M, qfrc_bias, qfrc_passive, subtree_com, geom_xpos),
                 (chain, m_rows, m_cols, points, point_bodies, leg_dofs, actuated, torque_limits, w2, params),
                 (qr, qdr, qddr, com_ref, com_ref_vel, cop_ref),
                 (contact, mass, np.full(n, -1.0), np.zeros((n, N_SWING))),
                 (warm, warm_out), (ext_f, ext_p, ext_bodies, np.zeros((n, 0, 3)), np.zeros((n, 0, 3))), (tau, info))
    for r in range(n):  # every plan found: keep the active sets (a singular plan raised, keeping none)
        s = ids[r]
        for j in range(warm.shape[1]):
            warm[s, j] = warm_out[s, j]
        rec_plan[s, k] = info[r, 2]  # the planned CoP, against the measured one after the step (plan vs execution)
    return _judge_tick(k, ids, clock, fields, consts, lean, state, now, tau,
                       (grounded, c_lo, c_hi, lowest, vel_x, roll), held, new)


@njit(cache=True, nogil=True)
def _judge_tick(k, ids, clock, fields, consts, lean, state, now, tau, read, held, new):
    """The end of ``control_tick``: the torques into ``ctrl_all`` (zero for a non-finite plan), then the balance
    monitor on rows ``ids`` (``read``: what the tick's geometry read, (grounded, c_lo, c_hi, lowest, vel_x,
    roll); ``held``: a mass held and not carried, added to the CoM it judges); ``new`` gets the rows that fell now;
    returns how many."""
    dt, control_dt, mass_kg = clock[0], clock[1], clock[3]
    qpos, subtree_com, time_s = fields[2], fields[11], fields[12]
    com_height_m, airborne_s, roll_rad, capture_margin_m = consts[9], consts[10], consts[11], consts[12]
    lean_check, prop_force, leaning_n = lean
    airborne_for_s, fall_code = state[0], state[1]
    ctrl_all = now[3]
    grounded, c_lo, c_hi, lowest, vel_x, roll = read
    n = ids.shape[0]
    nu = tau.shape[1]
    finite = np.empty(n, np.bool_)
    air = np.empty(n)
    for r in range(n):
        s = ids[r]
        ok = True
        for u in range(nu):
            if not np.isfinite(tau[r, u]):
                ok = False
        for u in range(nu):
            t = tau[r, u] if ok else 0.0
            ctrl_all[s, u] = t
        airborne_for_s[s] = 0.0 if grounded[r] else airborne_for_s[s] + control_dt
        air[r] = airborne_for_s[s]
        for j in range(qpos.shape[1]):
            if not np.isfinite(qpos[s, j]):
                ok = False
        finite[r] = ok and abs(time_s[s] - k * dt) < 1e-9
        if lean_check and k > 0 and prop_force[s, k - 1] > leaning_n:  # leaning on a prop
            c_lo[r], c_hi[r] = -np.inf, np.inf
    com_x, com_z, com_vel = np.empty(n), np.empty(n), np.empty(n)
    held_m, held_xz, held_vx = held[0], held[1], held[2]
    carried_kg = now[0]
    for r in range(n):
        com_x[r], com_z[r], com_vel[r] = subtree_com[ids[r], 1, 0], subtree_com[ids[r], 1, 2], vel_x[r]
        m = held_m[r]
        if m > 0.0:  # simulate._with_held's operations
            own = mass_kg + carried_kg[ids[r]]
            total = own + m
            com_x[r] = (own * com_x[r] + m * held_xz[r, 0]) / total
            com_z[r] = (own * com_z[r] + m * held_xz[r, 1]) / total
            com_vel[r] = (own * com_vel[r] + m * held_vx[r]) / total
    code = _first_failed(finite, lowest, com_x, com_z, com_vel, air, roll, c_lo, c_hi, com_height_m, airborne_s,
                         roll_rad, capture_margin_m)
    fell = 0
    for r in range(n):
        s = ids[r]
        new[r] = code[r] > 0 and fall_code[s] == 0
        if new[r]:
            fall_code[s] = code[r]
            fell += 1
    return fell


@njit(cache=True, nogil=True)
def sample_support(k, ids, geom_xpos, qpos, subtree_com, points, cop_ref_now, rec_sc, rec_lo, rec_hi, rec_qpos,
                   rec_com, rec_pref, sample_x):
    """A CoP sample step between control steps, rows ``ids`` (bound fields indexed by simulation): heel/toe
    x into ``sample_x`` and the support span, centre, joint angles, CoM and the held reference CoP into the
    records, as the Python path does (``min``/``max`` of the four points propagate NaN as numpy's do)."""
    npt = points.shape[0]
    nq_rec = rec_qpos.shape[2]
    for r in range(ids.shape[0]):
        s = ids[r]
        for p in range(npt):
            sample_x[s, k, p] = geom_xpos[s, points[p], 0]
        a, b = sample_x[s, k, 0], sample_x[s, k, 0]
        for p in range(1, npt):
            x = sample_x[s, k, p]
            if a == a:
                a = x if (x != x or x < a) else a
            if b == b:
                b = x if (x != x or x > b) else b
        rec_sc[s, k], rec_lo[s, k], rec_hi[s, k] = 0.5 * (a + b), a, b
        for j in range(nq_rec):
            rec_qpos[s, k, j] = qpos[s, j]
        rec_com[s, k, 0], rec_com[s, k, 1] = subtree_com[s, 1, 0], subtree_com[s, 1, 2]
        rec_pref[s, k] = cop_ref_now[s]
