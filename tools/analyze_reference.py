"""Is a pose-change task physically possible, and is it hard to balance?

For the task's reference motion with both feet flat (root placed by forward
kinematics from the feet at every instant), inverse dynamics of the whole body gives
the ground force and CoP the motion needs: F = Ldot - m g, CoP = c_x - (Hdot + c_z F_x)/F_z.

* possible at all: F_z > 0 throughout (the body is never asked to fall faster than gravity);
* hard to balance (ABC 4.1): the required CoP, or the CoM's ground projection, leaves the
  support interval, so the reference cannot be followed as is.

What the controller can give, and whether a CoM pre-shift (a CMRT) could make the motion possible:

* the QP presses every heel/toe point with at least ``min_point_force_n`` f (40 N), so with both
  feet flat its CoP lies in the **band** [heel + 2 f w / F_z, toe - 2 f w / F_z] (w the heel-to-toe
  length), which closes at the support centre as F_z falls to 4 f (160 N);
* ``cop_excess_m``: the largest distance of the required CoP beyond that band (signed: < 0 is a
  margin inside it; inf where the band is closed), for three horizontal CoM shifts dc(t) of the
  whole motion, which move the required CoP by dc - (m c_z / F_z) dc'' (the shift's own horizontal
  force; the joint motion, and so the angular momentum, is the reference's):
  ``none`` (the reference as written), ``from_motion_start`` (the best shift that is zero until the
  motion starts at P: whatever a controller that knows the whole future but only reacts once the
  motion begins could do) and ``any`` (the best shift over the clip: anticipation). Each best shift
  is a linear program on a 10 ms grid, zero with zero rate at the clip's ends (as a CMRT is),
  |dc| <= 0.3 m. ``from_motion_start`` > 0 and ``any`` <= 0 is "performable with a pre-shift, not
  without" - without counting on the motion being done late, which the tracking bound limits.
  It is a model, not the controller: the QP may also deviate single joints within the tracking
  bound, which no CoM shift describes. Measured on the 0.4 s bend (tools/bend_search.py): references
  with ``from_motion_start`` up to +0.5 m were still performed with the zero CMRT, and ``none`` is
  metres wherever F_z is small (the band's edges divide by it). Read the excesses with the zero-CMRT run.

    python tools/analyze_reference.py bend --speeds 0.4,0.6,0.8,1.2 [--json]
"""

from __future__ import annotations

import argparse
import json

import numpy as np
from scipy.optimize import linprog

from cmrt import character, load_task
from cmrt.control.controller import ControllerConfig
from cmrt.motion.loads import keyed_motion, loads

DT_S = 0.002
LP_STEP = 5  # the shifts' grid: every 5th 2 ms sample (10 ms)
MAX_SHIFT_M = 0.3


def analyze(task) -> dict:
    ch = character()
    motion = keyed_motion(task, DT_S)
    ld = loads(motion)
    t, com, qd = motion.t_s, ld.com_m, motion.qvel
    lo, hi = ld.heel_x_m, ld.toe_x_m
    fx, fz = ld.force_n[:, 0], ld.force_n[:, 1]
    cop = lo + ld.heel_moment_nm / fz  # as the formula gives it, also where the ground would have to pull
    band_lo, band_hi = cop_band(fz, lo, hi, ControllerConfig().min_point_force_n)
    xi = com[:, 0] + motion.com_vel_m_s[:, 0] / np.sqrt(9.81 / com[:, 1])
    p0, p1 = task.preparation_s, task.preparation_s + task.duration_s
    moving = (t >= p0) & (t <= p1)
    sub = slice(None, None, LP_STEP)
    arm = ch.mass_kg * com[sub, 1] / np.where(fz[sub] > 0, fz[sub], np.inf)
    mu = ControllerConfig().friction_coef
    fx_room = (mu * fz[sub] - fx[sub], mu * fz[sub] + fx[sub])  # room for the shift's m dc'' (+x, -x)
    from_start, shift_start = best_shift(cop[sub], band_lo[sub], band_hi[sub], arm, DT_S * LP_STEP,
                                         free_from=int(np.searchsorted(t[sub], p0)), fx_room=fx_room,
                                         mass_kg=ch.mass_kg)
    anyshift, shift_any = best_shift(cop[sub], band_lo[sub], band_hi[sub], arm, DT_S * LP_STEP, free_from=0,
                                     fx_room=fx_room, mass_kg=ch.mass_kg)
    out_toe, out_heel = t[cop > band_hi] - p0, t[cop < band_lo] - p0
    return {
        "task": task.name,
        "speed": task.speed,
        "support_interval_m": [lo, hi],
        "com_drop_m": float(com[0, 1] - com[:, 1].min()),
        "min_vertical_force_n": float(fz.min()),
        "min_vertical_force_bw": float(fz.min() / (ch.mass_kg * 9.81)),
        "possible": bool(fz.min() > 0),
        "required_cop_range_m": [float(cop.min()), float(cop.max())],
        "com_projection_range_m": [float(com[:, 0].min()), float(com[:, 0].max())],
        "capture_point_range_m": [float(xi[moving].min()), float(xi[moving].max())],
        "cop_leaves_support": bool(cop.min() < lo or cop.max() > hi),
        "com_leaves_support": bool(com[:, 0].min() < lo or com[:, 0].max() > hi),
        "max_joint_speed_rad_s": float(np.abs(qd[:, 3:]).max()),
        "cop_excess_m": {"none": excess(cop, band_lo, band_hi), "from_motion_start": from_start, "any": anyshift},
        "cop_excess_toe_heel_m": [side_excess(cop - band_hi, band_lo > band_hi),
                                  side_excess(band_lo - cop, band_lo > band_hi)],
        "cop_beyond_toe_band_s": [float(out_toe.min()), float(out_toe.max())] if out_toe.size else None,
        "cop_behind_heel_band_s": [float(out_heel.min()), float(out_heel.max())] if out_heel.size else None,
        "best_shift_range_m": {"from_motion_start": shift_start, "any": shift_any},
    }


def cop_band(fz: np.ndarray, lo: float, hi: float, point_force_n: float) -> tuple[np.ndarray, np.ndarray]:
    """The CoP the QP can plan with both feet flat: every heel and toe point (two of each) pressed with at
    least ``point_force_n``. Closed (lo > hi) where F_z < 4 point forces."""
    end = 2.0 * point_force_n * (hi - lo) / np.where(fz > 0, fz, 1e-9)
    return lo + end, hi - end


def side_excess(over: np.ndarray, closed: np.ndarray) -> float:
    return float(np.inf) if closed.any() else float(over.max())


def excess(cop: np.ndarray, band_lo: np.ndarray, band_hi: np.ndarray) -> float:
    """Largest distance of ``cop`` beyond the band (m; < 0: the smallest margin inside; inf: band closed)."""
    if np.any(band_lo > band_hi):
        return float("inf")
    return float(np.max(np.maximum(cop - band_hi, band_lo - cop)))


def best_shift(cop: np.ndarray, band_lo: np.ndarray, band_hi: np.ndarray, arm_s2: np.ndarray, step_s: float,
               free_from: int = 0, fx_room: tuple[np.ndarray, np.ndarray] | None = None,
               mass_kg: float = 1.0) -> tuple[float, list[float]]:
    """The horizontal CoM shift dc minimising the largest excess e of the shifted CoP
    cop + dc - arm dc'' beyond the band (a linear program): dc is zero with zero rate at the end and
    up to sample ``free_from`` (at least the first two samples). ``fx_room``: how much horizontal force
    the friction cone leaves for the shift's own m dc'' forward and backward (N, per sample; None: no
    limit). Returns (e, [min dc, max dc]); inf where the band is closed or friction cannot be met."""
    if np.any(band_lo > band_hi):
        return float("inf"), [0.0, 0.0]
    n = cop.size
    free = np.arange(max(2, free_from), n - 2)
    lap = np.zeros((n, n))
    for i in range(1, n - 1):
        lap[i, i - 1:i + 2] = [1.0, -2.0, 1.0]
    full = np.eye(n) - arm_s2[:, None] * lap / step_s**2  # shifted CoP = cop + full @ dc
    k = free.size
    ones = np.ones((n, 1))
    a_ub = np.vstack([np.hstack([full[:, free], -ones]), np.hstack([-full[:, free], -ones])])
    b_ub = np.concatenate([band_hi - cop, cop - band_lo])
    if fx_room is not None:  # -room_back <= m dc'' <= room_fwd
        acc = mass_kg * lap[:, free] / step_s**2
        zero = np.zeros((n, 1))
        a_ub = np.vstack([a_ub, np.hstack([acc, zero]), np.hstack([-acc, zero])])
        b_ub = np.concatenate([b_ub, fx_room[0], fx_room[1]])
    cost = np.zeros(k + 1)
    cost[-1] = 1.0
    res = linprog(cost, A_ub=a_ub, b_ub=b_ub, bounds=[(-MAX_SHIFT_M, MAX_SHIFT_M)] * k + [(None, None)],
                  method="highs")
    if res.status != 0:  # infeasible: friction alone cannot be met
        return float("inf"), [float("nan"), float("nan")]
    dc = np.zeros(n)
    dc[free] = res.x[:k]
    return excess(cop + full @ dc, band_lo, band_hi), [float(dc.min()), float(dc.max())]


def main() -> None:
    ap = argparse.ArgumentParser(description="inverse-dynamics check of a task's reference motion")
    ap.add_argument("task", nargs="?", default="bend")
    ap.add_argument("--speeds", default="0.4,0.5,0.6,0.8,1.2")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    base = load_task(args.task)
    rows = [analyze(base.with_speed(float(s))) for s in args.speeds.split(",")]
    if args.json:
        print(json.dumps(rows, indent=2))
        return
    lo, hi = rows[0]["support_interval_m"]
    print(f"{args.task}: support interval [{lo:.3f}, {hi:.3f}] m, CoM drop {rows[0]['com_drop_m']:.3f} m")
    print("          min Fz            required CoP       CoM range          CoP excess beyond the QP's band (m)")
    print(" speed   (N)     (BW)     range (m)            (m)                none    from motion start   any shift")
    for r in rows:
        ex = r["cop_excess_m"]
        print(
            f" {r['speed']:5.2f}  {r['min_vertical_force_n']:7.1f}  {r['min_vertical_force_bw']:5.2f}   "
            f"[{r['required_cop_range_m'][0]:+.3f}, {r['required_cop_range_m'][1]:+.3f}]   "
            f"[{r['com_projection_range_m'][0]:+.3f}, {r['com_projection_range_m'][1]:+.3f}]   "
            f"{ex['none']:+7.3f}   {ex['from_motion_start']:+7.3f}             {ex['any']:+7.3f}"
        )


if __name__ == "__main__":
    main()
