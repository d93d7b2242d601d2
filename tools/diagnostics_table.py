"""The diagnostics of issue 25 (planned vs executed CoP, timing lag, fall direction, the topple after a fall)
for the shipped tasks, zero and library CMRT, on recorded runs as ``cmrt simulate`` makes them - the
tables of docs/controller.md (*Diagnostics*). One clip at a time (run it alone on a shared machine).

    python tools/diagnostics_table.py [--json] [--case bend:0.4 ...]
"""

from __future__ import annotations

import argparse
import json
import time

from cmrt import evaluate, library_curve, load_task, simulate

CASES = ("bend:0.4", "bend:1.2", "punch", "push", "catch", "rise")
KEYS = ("success", "fell", "fall_time_s", "tracking_error_rad", "max_plan_cop_error_m", "timing_lag_s",
        "fall_direction", "fall_direction_source", "after_fall_max_joint_speed_rad_s",
        "after_fall_peak_foot_force_bw", "after_fall_max_foot_lift_m", "after_fall_floor_contact_s")


def row(case: str, curve_name: str) -> dict:
    """One recorded clip of ``case`` (task[:speed]) with the zero or the library CMRT."""
    name, _, speed = case.partition(":")
    task = load_task(name)
    if speed:
        task = task.with_speed(float(speed))
    curve = None if curve_name == "zero" else library_curve(task)
    t0 = time.perf_counter()
    ev = evaluate(task, simulate(task, curve))
    out = {"case": case, "curve": curve_name, **{k: getattr(ev, k) for k in KEYS}}
    return {**out, "wall_s": round(time.perf_counter() - t0, 1)}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", action="store_true")
    p.add_argument("--case", action="append", help="task[:speed] (default: the shipped table)")
    p.add_argument("--curve", action="append", choices=("zero", "library"))
    args = p.parse_args()
    for case in args.case or CASES:
        for curve in args.curve or ("zero", "library"):
            r = row(case, curve)
            if args.json:
                print(json.dumps(r), flush=True)
            else:
                print("  ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in r.items()),
                      flush=True)


if __name__ == "__main__":
    main()
