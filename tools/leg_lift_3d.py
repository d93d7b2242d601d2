"""The 3D body lifting a foot (the ``leg-lift`` task; docs/body3d.md): per speed T, the verdict, when it fell, how
far the CoM moved toward the stance foot before lift-off, how high the foot went and how late; or a filmstrip.

    python tools/leg_lift_3d.py [--json] [--speeds 1.5,2.3,3.0,3.5] [--reference center|yu] [--curve zero]
    python tools/leg_lift_3d.py --speeds 2.3 --curve library                   # the library's CMRT
    python tools/leg_lift_3d.py --filmstrip docs/body3d_leg_lift_filmstrip.png --speeds 2.3 --curve library

``--reference center`` (the task's, the paper's): the CoM's and CoP's reference the support's centre - both feet,
then the stance foot from lift-off - plus the CMRT in y; ``yu``: the reference motion's own weight shift.
``--curve``: zero, library, a stored run or a CMRT file, as ``cmrt simulate`` takes it (a file's CMRT is used at
every speed it lists). ``--set KEY=VALUE`` as ``cmrt simulate`` (``stance_side=-1`` stands on the right foot).
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from cmrt import CmrtError, resolve_curve, resolve_task, simulate_report
from cmrt.inputs import parse_sets
from cmrt.modes import REFERENCE_MODES
from cmrt.sim.clip3d import clip_3d

FRAMES_AFTER_LIFT_OFF = (0.4, 1.0)  # of the lift's duration: mid-lift and lifted


def row(speed: float, reference: str, curve_spec: str, sets: dict) -> dict:
    """One leg lift at T = ``speed``: its report's verdict and leg-lift figures."""
    task = resolve_task("leg-lift", speed, sets, reference)
    curve, name = resolve_curve(curve_spec, task, None, "--curve", other_task=True)
    r = simulate_report(task, curve, name)
    keys = ("speed", "reference", "curve", "success", "failed_rules", "fell", "fall_time_s", "fall_direction_xy",
            "lift_off_s", "com_shift_toward_stance_before_lift_off_m", "foot_lift_m", "timing_lag_s",
            "timing_lag_bound_s", "max_plan_cop_error_m", "min_cop_margin_m", "peak_normal_force_bw",
            "max_foot_slip_m", "objective")
    return {k: r[k] for k in keys}


def _floats(text: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a comma-separated list of numbers: {text!r}") from None
    if not values:
        raise argparse.ArgumentTypeError(f"no speeds in {text!r}")
    return values


def filmstrip(speed: float, reference: str, curve_spec: str, sets: dict, out: str) -> dict:
    """Render one leg lift: standing, mid-shift, lift-off, mid-lift, lifted, the end (front row over side)."""
    from cmrt.viz.render3d import filmstrip_3d

    task = resolve_task("leg-lift", speed, sets, reference)
    curve, _ = resolve_curve(curve_spec, task, None, "--curve", other_task=True)
    c = clip_3d(task, curve)
    p = task.params
    lift_off, lift_s = c.lift.lift_off_s, p["lift_fraction"] * p["duration_s"]
    times = np.array([0.4, 0.5 * (p["preparation_s"] + lift_off), lift_off,
                      *(lift_off + f * lift_s for f in FRAMES_AFTER_LIFT_OFF), p["clip_s"] - 0.1])
    return filmstrip_3d(c.result, times, out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="machine-readable output")
    parser.add_argument("--speeds", type=_floats, default=[1.5, 2.3, 3.0, 3.5], help="T values, s")
    parser.add_argument("--reference", choices=REFERENCE_MODES, default="center")
    parser.add_argument("--curve", default="zero", help="zero | library | RUN | FILE.json (default zero)")
    parser.add_argument("--set", action="append", metavar="KEY=VALUE", help="a task parameter, as cmrt simulate")
    parser.add_argument("--filmstrip", metavar="OUT.png", help="render the first speed's clip instead")
    args = parser.parse_args(argv)
    try:
        sets = parse_sets(args.set)
        if args.filmstrip:
            done = filmstrip(args.speeds[0], args.reference, args.curve, sets, args.filmstrip)
            print(json.dumps(done) if args.json else f"wrote {done['out']}")
            return 0
        rows = [row(s, args.reference, args.curve, sets) for s in args.speeds]
    except CmrtError as exc:
        print(f"leg_lift_3d: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(rows, indent=1) if args.json else "\n".join(map(_line, rows)))
    return 0


def _line(r: dict) -> str:
    """One row as text."""
    verdict = "success" if r["success"] else "not: " + ", ".join(r["failed_rules"])
    fall = f", fell at {r['fall_time_s']:.2f} s (lift-off {r['lift_off_s']:.2f} s)" if r["fell"] else ""
    late = "-" if r["timing_lag_s"] is None else f"{r['timing_lag_s']:.3f} s"
    return (f"T {r['speed']:.2f} s, {r['reference']}, {r['curve']}: {verdict}{fall}; CoM "
            f"{100 * r['com_shift_toward_stance_before_lift_off_m']:.1f} cm toward the stance foot at lift-off, "
            f"foot up {100 * r['foot_lift_m']:.1f} cm, late {late}")


if __name__ == "__main__":
    raise SystemExit(main())
