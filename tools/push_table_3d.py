"""The 3D body standing and pushed (docs/body3d.md's table): each push's verdict and figures, measured with
``cmrt.sim.spatial.stand_3d`` - standing 10 s, then a 0.1 s thorax push 1 s into a 4 s clip per force and
direction (degrees about z from +x, forward; 90 is the body's left).

    python tools/push_table_3d.py [--json] [--forces 100,150,200,300] [--directions 0,180,90,270]
    python tools/push_table_3d.py --filmstrip docs/body3d_push_filmstrip.png --forces 300 --directions 90

``--filmstrip`` renders the first pushed clip (front view over side view, ``cmrt.viz.render3d``) instead of the
table.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

from cmrt.errors import CmrtError
from cmrt.sim.spatial import stand_3d

STANDING_S = 10.0
PUSHED_S = 4.0


def row(label: str, clip_s: float, push_n: tuple[float, float, float]) -> dict:
    """One clip's verdict and figures."""
    start = time.perf_counter()
    r = stand_3d(clip_s=clip_s, push_n=push_n)
    return {"clip": label, "success": r.success, "failed_rules": list(r.failed_rules), "fell": r.fell,
            "fall_time_s": r.fall_time_s,
            "fall_direction_xy": None if r.fall_direction_xy is None else [round(float(v), 3)
                                                                          for v in r.fall_direction_xy],
            "max_plan_cop_error_m": r.max_plan_cop_error_m, "min_cop_margin_m": r.min_cop_margin_m,
            "final_com_speed_m_s": r.final_com_speed_m_s, "infeasible_steps": r.infeasible_steps,
            "peak_normal_force_bw": r.peak_normal_force_bw, "airborne_s": r.airborne_s,
            "max_joint_speed_rad_s": r.max_joint_speed_rad_s, "max_foot_slip_m": r.max_foot_slip_m,
            "topple_direction_xy": None if r.topple_direction_xy is None else [round(float(v), 3)
                                                                              for v in r.topple_direction_xy],
            "wall_s": round(time.perf_counter() - start, 2)}


def _floats(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a comma-separated list of numbers: {text!r}") from None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="machine-readable output")
    parser.add_argument("--forces", type=_floats, default=[100.0, 150.0, 200.0, 300.0], help="push forces, N")
    parser.add_argument("--directions", type=_floats, default=[0.0, 180.0, 90.0, 270.0],
                        help="push directions, degrees about z from forward (+x)")
    parser.add_argument("--no-standing", action="store_true", help="skip the 10 s standing clip")
    parser.add_argument("--filmstrip", metavar="OUT.png", help="render the first force and direction's clip")
    parser.add_argument("--frames", type=_floats, default=[0.9, 1.1, 1.3, 1.6, 2.0, 2.6],
                        help="the filmstrip's times, s")
    args = parser.parse_args(argv)
    if any(f < 0 for f in args.forces):
        parser.error("--forces: a force is a magnitude (>= 0 N); the direction says where it points")
    if args.filmstrip:
        return _filmstrip(args)
    rows = [] if args.no_standing else [row("standing 10 s", STANDING_S, (0.0, 0.0, 0.0))]
    for force in args.forces:
        for deg in args.directions:
            a = math.radians(deg)
            push = (force * round(math.cos(a), 12), force * round(math.sin(a), 12), 0.0)  # 90 deg: exactly +y
            rows.append(row(f"{force:g} N at {deg:g} deg", PUSHED_S, push))
    if args.json:
        print(json.dumps(rows, indent=1))
    else:
        for r in rows:
            verdict = "success" if r["success"] else "not: " + ", ".join(r["failed_rules"])
            fall = f", fell at {r['fall_time_s']:.2f} s toward {r['fall_direction_xy']}" if r["fell"] else ""
            print(f"{r['clip']:>20}: {verdict}{fall}; plan {1000 * r['max_plan_cop_error_m']:.2f} mm, "
                  f"margin {100 * r['min_cop_margin_m']:.1f} cm, ground {r['peak_normal_force_bw']:.2f} BW, "
                  f"joints {r['max_joint_speed_rad_s']:.2f} rad/s, slide {1000 * r['max_foot_slip_m']:.1f} mm "
                  f"({r['wall_s']} s)")
    return 0


def _filmstrip(args: argparse.Namespace) -> int:
    """The first force and direction's clip as a front-over-side filmstrip."""
    from cmrt.viz.render3d import filmstrip_3d

    a = math.radians(args.directions[0])
    push = (args.forces[0] * round(math.cos(a), 12), args.forces[0] * round(math.sin(a), 12), 0.0)
    result = stand_3d(clip_s=max(PUSHED_S, max(args.frames) + 0.1), push_n=push)
    try:
        written = filmstrip_3d(result, args.frames, args.filmstrip)
    except CmrtError as exc:
        print(f"push_table_3d: {exc}", file=sys.stderr)
        return 2
    written.update(fell=result.fell, fall_time_s=result.fall_time_s)
    print(json.dumps(written) if args.json else f"wrote {written['out']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
