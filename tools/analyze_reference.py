"""Is a pose-change task physically possible, and is it hard to balance?

For the task's reference motion with both feet flat (root placed by forward
kinematics from the feet at every instant), inverse dynamics of the whole body gives
the ground force and CoP the motion needs: F = Ldot - m g, CoP = c_x - (Hdot + c_z F_x)/F_z.

* possible at all: F_z > 0 throughout (the body is never asked to fall faster than gravity);
* hard to balance (ABC 4.1): the required CoP, or the CoM's ground projection, leaves the
  support interval, so the reference cannot be followed as is.

    python tools/analyze_reference.py bend --speeds 0.4,0.6,0.8,1.2 [--json]
"""

from __future__ import annotations

import argparse
import json

import mujoco
import numpy as np

from cmrt.character import character, feet_flat_qpos, support_interval_x
from cmrt.control.momentum import centroidal_momentum_matrix
from cmrt.task import load_task

DT_S = 0.002


def analyze(task) -> dict:
    ch = character()
    m = ch.model
    d = mujoco.MjData(m)
    t = np.arange(0.0, task.clip_s, DT_S)
    q_ref = task.reference(t)[0]
    names = ch.dof_names
    q = np.array(
        [feet_flat_qpos({n: qr[i] for i, n in enumerate(names) if i >= 3}, balance_joint=None) for qr in q_ref]
    )
    qd = np.gradient(q, DT_S, axis=0)
    mom, com = [], []
    for k in range(len(t)):
        d.qpos[:] = q[k]
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mom.append(centroidal_momentum_matrix(m, d) @ qd[k])
        com.append(d.subtree_com[1, [0, 2]].copy())
    lo, hi = support_interval_x(d)
    mom, com = np.array(mom), np.array(com)
    rate = np.gradient(mom, DT_S, axis=0)
    fx, fz = rate[:, 0], rate[:, 1] + ch.mass_kg * 9.81
    cop = com[:, 0] - (rate[:, 2] + com[:, 1] * fx) / fz
    return {
        "task": task.name,
        "speed": task.speed,
        "support_interval_m": [lo, hi],
        "com_drop_m": float(com[0, 1] - com[:, 1].min()),
        "min_vertical_force_n": float(fz.min()),
        "possible": bool(fz.min() > 0),
        "required_cop_range_m": [float(cop.min()), float(cop.max())],
        "com_projection_range_m": [float(com[:, 0].min()), float(com[:, 0].max())],
        "cop_leaves_support": bool(cop.min() < lo or cop.max() > hi),
        "com_leaves_support": bool(com[:, 0].min() < lo or com[:, 0].max() > hi),
    }


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
    print(" speed   min Fz (N)   required CoP range (m)   CoM range (m)     CoP out  CoM out")
    for r in rows:
        print(
            f" {r['speed']:5.2f}   {r['min_vertical_force_n']:9.1f}   [{r['required_cop_range_m'][0]:+.3f}, "
            f"{r['required_cop_range_m'][1]:+.3f}]       [{r['com_projection_range_m'][0]:+.3f}, "
            f"{r['com_projection_range_m'][1]:+.3f}]   {r['cop_leaves_support']!s:5}    {r['com_leaves_support']}"
        )


if __name__ == "__main__":
    main()
