"""A 3D clip without a prop, stepped whole in compiled code: the loop of ``cmrt.sim.spatial.stand_3d`` with MuJoCo's
``mj_step`` called from numba (``cmrt.sim.mjc``), and its open-loop replay, the floor ``cmrt bench`` times.

Why: a leg lift's control step is four physics steps (68 us) and a plan (31 us); the Python around them - four
binding calls, the samples, the targets, the controller's wrapper - cost 28 us more, and the Python loop made a
clip 1.98 x its physics (docs/performance.md). Here the only Python is before and after the clip. A motion's targets
are a ``SpatialTargetTable`` made before the clip (they depend on time alone); a prop's logic runs in Python every
physics step, so a clip with a prop keeps ``stand_3d``'s Python loop. Both write the same samples
(``spatial.ClipSamples``) and are the same clip bit for bit (tests/sim/test_spatial_loop.py).

The compiled functions take grouped tuples (their layouts are in ``run_clip``'s and ``replay_clip``'s docstrings);
the protective mode a fall starts writes the clip's own model's arrays (its copy: ``spatial._clip_start``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cmrt.control import dual_qp
from cmrt.control import spatial_kernel as sk


@njit(cache=True, nogil=True)
def run_clip(step, subtree_vel, addresses, data, clip, controller, table, judge, out):  # pragma: no cover - compiled
    """Step a clip from its first physics step to its last; returns (the physics step of the fall or -1, the
    capture point's offset there (2), the control steps without a plan within the limits).

    ``step``, ``subtree_vel``: ``mj_step`` and ``mj_subtreeVel`` (ctypes); ``addresses``: (model, data).
    ``data``: (qpos, qvel, ctrl, xfrc_applied, the points' touch sensors, geom_xpos, subtree_com, subtree_linvel,
    xmat, plan_step's fields) - views of the clip's MjData. ``clip``: (physics steps, physics steps per control
    step, timestep s, the first judged time s, the push (3, N), its start and end s, the thorax body, the points'
    geoms, the actuated dofs, the planted force N, the points' radius m, the on-floor height m). ``controller``:
    (``SpatialController.compiled_parts()``, the body's mass kg, the CoM held (3)). ``table``:
    ``SpatialController.table_arrays``. ``judge``: (the feet's bodies, their soles, the fall rules' limits, the
    protective mode's (joints, their dofs, their qpos, stiffness, damping, and the model's jnt_stiffness,
    dof_damping, qpos_spring)). ``out``: ``ClipSamples.arrays()``."""
    model_address, data_address = addresses
    qpos, qvel, ctrl, xfrc, sensors, geom_xpos, subtree_com, subtree_linvel, xmat, fields = data
    steps, every, dt, settle_s, push, push_start, push_end, thorax, points, acts, planted_n, radius, floor_m = clip
    parts, mass, com_ref = controller
    body, gains, targets, held_bodies, load_gen, history, count, active = parts
    com_xy, com_vel, cop_ref, q_ref, qd_ref, qdd_ref, swing, swing_pos, swing_vel = table
    feet, soles, limits, protective = judge
    com_out, cop_out, plan_out, qpos_out, margin_out, planted_out, speed_out, ctrl_out, touches = out
    n_pts = points.size
    fall_k, offset, infeasible = -1, np.zeros(2), 0
    held_cop = np.full(2, np.nan)
    pushing = False
    xy = np.empty((n_pts, 2))
    loaded = np.empty(n_pts, dtype=np.bool_)
    for k in range(steps):
        t = k * dt
        if k % every == 0:
            i = k // every
            touch = sensors.copy()
            for p in range(n_pts):
                xy[p, 0], xy[p, 1] = geom_xpos[points[p], 0], geom_xpos[points[p], 1]
            cop = executed_cop(touch, xy)
            com_out[i], cop_out[i], plan_out[i], qpos_out[i] = subtree_com[1], cop, held_cop, qpos
            margin_out[i], planted_out[i], speed_out[i] = sample(cop, touch, xy, qvel, acts, planted_n)
            if fall_k < 0 and t >= settle_s:
                subtree_vel(model_address, data_address)
                fell, offset = fall_rules(subtree_com[1], subtree_linvel[1], touch, geom_xpos, soles, xmat, feet,
                                          False, limits)
                if fell:
                    fall_k = k
                    protect(protective, qpos, ctrl)
            if fall_k < 0:
                for p in range(n_pts):
                    loaded[p] = geom_xpos[points[p], 2] - radius < floor_m
                sk.write_targets(targets, com_ref, com_xy[i], com_vel[i], cop_ref[i], swing[i], swing_pos[i],
                                 swing_vel[i], 0.0, mass)
                torque, _, planned, status, limited = sk.plan_step(
                    fields, body, gains, targets, (q_ref[i], qd_ref[i], qdd_ref[i]), loaded, load_gen, held_bodies,
                    history, count, active)
                finite = True
                for j in range(torque.size):
                    finite = finite and np.isfinite(torque[j])
                if status != dual_qp.OPTIMAL or not finite:  # no plan: the body is lost, scored as a fall
                    infeasible += 1
                    fall_k, offset = k, np.zeros(2)
                    protect(protective, qpos, ctrl)
                else:
                    infeasible += not limited
                    ctrl[:] = torque
                    held_cop = planned
            if fall_k >= 0:
                held_cop = np.full(2, np.nan)
            ctrl_out[i] = ctrl
        if (push_start <= t < push_end) != pushing:  # the push starts or ends
            pushing = not pushing
            for a in range(3):
                xfrc[thorax, a] = push[a] if pushing else 0.0
        step(model_address, data_address)
        touches[k] = sensors
    return fall_k, offset, infeasible


@njit(cache=True, nogil=True)
def replay_clip(step, addresses, data, clip, ctrl_nm, fall_sample, protective, com_out):  # pragma: no cover
    """``run_clip``'s physics alone: the recorded torques ``ctrl_nm`` (samples, nu) written at each control step,
    the push, the protective mode from sample ``fall_sample`` (-1: none). ``data``: (qpos, ctrl, xfrc_applied,
    subtree_com); ``clip``: (physics steps, per control step, timestep s, the push (3), its start and end s, the
    thorax body); ``com_out``: (samples, 3) filled with the CoM at each sample, or (0, 3) not to. Returns the
    physics steps taken."""
    model_address, data_address = addresses
    qpos, ctrl, xfrc, subtree_com = data
    steps, every, dt, push, push_start, push_end, thorax = clip
    record = com_out.shape[0] > 0
    for k in range(steps):
        t = k * dt
        if k % every == 0:
            sample_i = k // every
            if record:
                com_out[sample_i] = subtree_com[1]
            if sample_i == fall_sample:
                protect(protective, qpos, ctrl)
            ctrl[:] = ctrl_nm[sample_i]
        on = push_start <= t < push_end
        for a in range(3):
            xfrc[thorax, a] = push[a] if on else 0.0
        step(model_address, data_address)
    return steps


@njit(cache=True, nogil=True)
def protect(protective, qpos, ctrl):  # pragma: no cover - compiled
    """The planar protective mode (``spatial._protective``): motors off, every actuated joint a passive spring and
    damper about the pose it fell in - written into the clip's own model."""
    joints, dofs, qadr, stiffness, damping, jnt_stiffness, dof_damping, qpos_spring = protective
    for j in range(joints.size):
        jnt_stiffness[joints[j]] = stiffness[j]
        dof_damping[dofs[j]] = damping[j]
        qpos_spring[qadr[j]] = qpos[qadr[j]]
    ctrl[:] = 0.0


@njit(cache=True, nogil=True)
def executed_cop(touch, xy):  # pragma: no cover - compiled
    """The CoP of the touch sensors' forces at the points' places (m; NaN with no force), summed in the points'
    order - one arithmetic for every clip and machine (numpy's matrix product was BLAS's, its order its own)."""
    total, x, y = 0.0, 0.0, 0.0
    for p in range(touch.size):
        total += touch[p]
        x += touch[p] * xy[p, 0]
        y += touch[p] * xy[p, 1]
    if total > 0.0:
        return np.array([x / total, y / total])
    return np.full(2, np.nan)


@njit(cache=True, nogil=True)
def fall_rules(com, vel, touch, geom_xpos, soles, xmat, feet, leaning, limits):  # pragma: no cover - compiled
    """``spatial._fallen``'s rules, compiled (numpy's dozen small calls a control step were a tenth of a clip):
    whether the body fell, and the capture point's offset from the touching soles' centre. ``soles`` (2, points per
    foot): each foot's geoms, the right's first; ``limits``: (cos of the roll limit, capture margin m, CoM height m,
    gravity m/s^2). The arithmetic is numpy's, in its order (a mean is a sum in order over the count)."""
    scale = np.sqrt(limits[3] / max(com[2], 1e-3))
    capture = np.array([com[0] + vel[0] / scale, com[1] + vel[1] / scale])
    half = touch.size // 2  # each foot's points: the right's, then the left's
    on = (touch[:half].max() > 0.0, touch[half:].max() > 0.0)
    count = 0
    for foot in range(2):
        count += soles.shape[1] if on[foot] else 0
    sole_xy = np.empty((count, 2))
    k = 0
    for foot in range(2):
        if on[foot]:
            for g in soles[foot]:
                sole_xy[k, 0], sole_xy[k, 1] = geom_xpos[g, 0], geom_xpos[g, 1]
                k += 1
    centre = np.array([com[0], com[1]])
    if count:
        total = np.zeros(2)
        for i in range(count):
            total = total + sole_xy[i]
        centre = total / count
    rolled = False
    for body in feet:
        rolled = rolled or xmat[body, 8] < limits[0]  # a sole's normal's z
    out = count == 0 or hull_margin(capture[0], capture[1], sole_xy) < -limits[1]
    out = out and not leaning
    return rolled or out or com[2] < limits[2], capture - centre


@njit(cache=True, nogil=True)
def hull_margin(x: float, y: float, pts: np.ndarray) -> float:  # pragma: no cover - compiled
    """``spatial._margin``, compiled (the clip's samples and fall rules call it too): 0 for a point that is not
    finite or fewer than three points; else each ordered pair (i, j) is an edge of the hull when every point lies on
    or behind the line i -> j turned clockwise (tolerance 1e-9 of the points' span), and the margin is the smallest
    distance to an edge's line, negative outside."""
    n = pts.shape[0]
    if not (np.isfinite(x) and np.isfinite(y)) or n < 3:
        return 0.0
    scale = 1e-12
    for i in range(n):
        for j in range(n):
            scale = max(scale, abs(pts[j, 0] - pts[i, 0]), abs(pts[j, 1] - pts[i, 1]))
    tol = 1e-9 * scale
    flat = True  # every point on every edge's line: no area
    best = -np.inf  # the largest signed distance outside a hull edge
    for i in range(n):
        for j in range(n):
            nx, ny = pts[j, 1] - pts[i, 1], -(pts[j, 0] - pts[i, 0])
            length = np.sqrt(nx * nx + ny * ny)
            if not length > tol:
                continue
            ux, uy = nx / length, ny / length
            behind = True
            for k in range(n):
                side = ux * (pts[k, 0] - pts[i, 0]) + uy * (pts[k, 1] - pts[i, 1])
                if abs(side) > tol:
                    flat = False
                if side > tol:
                    behind = False
            if behind:
                best = max(best, ux * (x - pts[i, 0]) + uy * (y - pts[i, 1]))
    if flat or best == -np.inf:
        return 0.0
    return -best


@njit(cache=True, nogil=True)
def sample(cop, touch, xy, qvel, acts, planted_n):  # pragma: no cover - compiled
    """A control step's sample beside the CoP: the CoP's margin inside the touching points (``hull_margin``), each
    point's place where it carries ``planted_n`` or more (NaN elsewhere) and the fastest actuated joint (rad/s) -
    compiled, as numpy's small calls were a control step's cost; the arithmetic is theirs."""
    n = touch.size
    touching = 0
    for p in range(n):
        touching += touch[p] > 0.0
    pts = np.empty((touching, 2))
    k = 0
    for p in range(n):
        if touch[p] > 0.0:
            pts[k, 0], pts[k, 1] = xy[p, 0], xy[p, 1]
            k += 1
    margin = hull_margin(cop[0], cop[1], pts)
    planted = np.empty((n, 2))
    for p in range(n):
        on = 1.0 if touch[p] >= planted_n else np.nan
        planted[p, 0], planted[p, 1] = on * xy[p, 0], on * xy[p, 1]
    speed = 0.0
    for j in acts:
        speed = max(speed, abs(qvel[j]))
    return margin, planted, speed


@njit(cache=True, nogil=True)
def planted_slide(planted_xy):  # pragma: no cover - compiled
    """How far any point slid while planted (m): ``planted_xy`` (samples, points, 2), NaN where a point is not
    planted; each run of planted samples measured from its first - compiled, as numpy's dozen array passes were a
    fifth of a clip's Python; the arithmetic is theirs (sqrt(dx * dx + dy * dy))."""
    best = 0.0  # a run's first sample is 0 from itself, so the largest distance over any planted sample
    for p in range(planted_xy.shape[1]):
        first = -1
        for i in range(planted_xy.shape[0]):
            x, y = planted_xy[i, p, 0], planted_xy[i, p, 1]
            if np.isnan(x) or np.isnan(y):
                first = -1
                continue
            if first < 0:
                first = i
            dx, dy = x - planted_xy[first, p, 0], y - planted_xy[first, p, 1]
            best = max(best, np.sqrt(dx * dx + dy * dy))
    return best
