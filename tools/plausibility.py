"""What a researcher would see in each clip: is the motion physically plausible?

For every shipped task (and standing pushes) with the zero CMRT and the library CMRT:
success, fall time and reason, peak vertical ground force over body weight, time
airborne, the fastest actuated joint, the smallest CoP margin to the edge of the feet,
and the tracking error - all before any fall, from ``cmrt.evaluate``.

    python tools/plausibility.py [--json]
"""

from __future__ import annotations

import argparse
import json

from cmrt import CmrtError, evaluate, library_curve, load_task
from cmrt.sim.simulate import simulate_batch

CASES = [
    ("stand", {}), ("stand", {"push_force_n": 100.0, "push_duration_s": 0.1}),
    ("stand", {"push_force_n": -100.0, "push_duration_s": 0.1}),
    ("bend", {"duration_s": 0.4}), ("bend", {"duration_s": 1.2}), ("rise", {"duration_s": 0.4}),
    ("punch", {}), ("catch", {}), ("push", {}),
]


def rows() -> list[dict]:
    out = []
    for name, params in CASES:
        task = load_task(name).with_params(**params) if params else load_task(name)
        curves = [("zero", None)]
        try:
            curves.append(("library", library_curve(task)))
        except CmrtError:
            pass
        trajs = simulate_batch(task, [c for _, c in curves])
        for (label, _), traj in zip(curves, trajs, strict=True):
            ev = evaluate(task, traj)
            out.append({
                "task": name, "params": params, "curve": label, "success": ev.success, "performed": ev.performed,
                "fell": ev.fell, "fall_time_s": ev.fall_time_s, "fall_reason": ev.fall_reason,
                "peak_normal_force_bw": ev.peak_normal_force_bw, "airborne_s": ev.airborne_s,
                "max_joint_speed_rad_s": ev.max_joint_speed_rad_s, "min_cop_margin_m": ev.min_cop_margin_m,
                "tracking_error_rad": ev.tracking_error_rad, "objective": ev.objective,
                "failed_rules": list(ev.failed_rules),
            })
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    table = rows()
    if args.json:
        print(json.dumps(table, indent=2))
        return
    print(f"{'task':<26} {'curve':<8} {'success':<8} {'fall':<42} {'GRF/BW':>6} {'air s':>6} {'joint':>6} "
          f"{'margin':>7} {'track':>6}  failed rules")
    for r in table:
        short = {"push_force_n": "push {:g} N", "push_duration_s": "x {:g} s", "duration_s": "T {:g} s"}
        label = " ".join([r["task"]] + [short[k].format(v) for k, v in r["params"].items()])
        fall = f"{r['fall_time_s']:.2f} s {r['fall_reason']}" if r["fell"] else "-"
        track = "-" if r["tracking_error_rad"] != r["tracking_error_rad"] else f"{r['tracking_error_rad']:.3f}"
        print(f"{label:<26} {r['curve']:<8} {str(r['success']):<8} {fall:<42} {r['peak_normal_force_bw']:6.2f} "
              f"{r['airborne_s']:6.3f} {r['max_joint_speed_rad_s']:6.1f} {100 * r['min_cop_margin_m']:5.1f}cm "
              f"{track:>6}  {', '.join(r['failed_rules']) or '-'}")


if __name__ == "__main__":
    main()
