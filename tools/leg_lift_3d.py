"""The 3D body lifting a foot (``cmrt.sim.spatial.leg_lift_3d``; docs/body3d.md): per weight-shift duration, the
verdict, when it fell, how high the foot went and where the CoM was at lift-off; or a filmstrip of one.

    python tools/leg_lift_3d.py [--json] [--shifts 1.0,1.5,2.0,2.5] [--stance left]
    python tools/leg_lift_3d.py --filmstrip docs/body3d_leg_lift_filmstrip.png --shifts 2.0
    python tools/leg_lift_3d.py --shifts 1.5 --cmrt tests/data/cmrt_leg_lift_3d.json    # the paper's centre mode

``--cmrt zero|FILE.json``: the paper's reference instead of the poses' CoM - the support's centre, displaced
sideways by that CMRT (a file: a CMRT, or a record with one under "cmrt"; its clip sets the clip's length).

``--optimize EVALS``: CMA-ES over the CMRT in y of the first shift in that centre mode (the driver's options: from
the zero CMRT, sigma 0.5, population 10, a private generator seeded by ``--seed``), minimizing
``cop_error_objective`` against the support's centre; ``--out`` writes the best with its provenance (how
tests/data/cmrt_leg_lift_3d.json was made):

    python tools/leg_lift_3d.py --shifts 1.5 --optimize 210 --seed 1 --out tests/data/cmrt_leg_lift_3d.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import mujoco
import numpy as np

from cmrt import inputs
from cmrt.body.character import character
from cmrt.body.one_leg import one_leg_poses
from cmrt.errors import CmrtError
from cmrt.motion.curve import Cmrt
from cmrt.optimize.driver import OptimizeSettings, new_state
from cmrt.sim.spatial import cop_error_objective, leg_lift_3d, stand_pose_qpos

START_S, LIFT_S, HOLD_S = 0.5, 0.8, 2.0  # the shift starts at START_S; the lift takes LIFT_S; then HOLD_S on one leg
SIGMA0, POPSIZE = 0.5, 10  # the driver's defaults from the zero CMRT
STANCES = {"right": 0, "left": 1}


def row(shift_s: float, stance: int, curve: Cmrt | None = None) -> dict:
    """One leg lift: its verdict and figures."""
    clip_s = curve.clip_s if curve is not None else START_S + shift_s + LIFT_S + HOLD_S
    r, lift_m = leg_lift_3d(shift_s=shift_s, lift_s=LIFT_S, clip_s=clip_s, stance=stance, cmrt_y=curve)
    k = max(int(np.searchsorted(r.time_s, START_S + shift_s)) - 1, 0)
    return {"shift_s": shift_s, "success": r.success, "failed_rules": list(r.failed_rules), "fell": r.fell,
            "fall_time_s": r.fall_time_s, "lift_off_s": START_S + shift_s, "foot_lift_m": lift_m,
            "com_at_lift_off_m": [float(v) for v in r.com_m[k]], "max_plan_cop_error_m": r.max_plan_cop_error_m,
            "min_cop_margin_m": r.min_cop_margin_m, "max_foot_slip_m": r.max_foot_slip_m}


def _curve(spec: str | None, shift_s: float) -> Cmrt | None:
    """``--cmrt``: None (the poses' CoM), the zero CMRT over the default clip, or a file's."""
    if spec is None:
        return None
    if spec == "zero":
        return Cmrt.zero(START_S + shift_s + LIFT_S + HOLD_S)
    try:
        raw = json.loads(Path(spec).read_text())
    except (OSError, ValueError) as exc:
        raise CmrtError(f"--cmrt {spec!r}: {exc}") from None
    return Cmrt.from_dict(raw.get("cmrt", raw) if isinstance(raw, dict) else raw, f"--cmrt {spec!r}")


def _floats(text: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a comma-separated list of numbers: {text!r}") from None
    if not values or any(not 0.2 <= v <= 10.0 for v in values):
        raise argparse.ArgumentTypeError(f"shifts are 0.2-10 s, got {text!r}")
    return values


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="machine-readable output")
    parser.add_argument("--shifts", type=_floats, default=[1.0, 1.5, 2.0, 2.5], help="weight-shift durations, s")
    parser.add_argument("--stance", choices=sorted(STANCES), default="left", help="the foot stood on")
    parser.add_argument("--filmstrip", metavar="OUT.png", help="render the first shift's clip instead")
    parser.add_argument("--cmrt", metavar="zero|FILE.json", help="the paper's centre mode with this CMRT in y")
    parser.add_argument("--optimize", type=int, metavar="EVALS", help="CMA-ES for the centre mode's CMRT in y")
    parser.add_argument("--seed", type=int, default=1, help="the search's seed (default 1)")
    parser.add_argument("--out", metavar="FILE.json", help="with --optimize: write the best CMRT and how it was found")
    args = parser.parse_args(argv)
    if args.optimize is not None:
        if args.optimize < 1:
            parser.error("--optimize: at least one evaluation")
        try:
            if args.out:
                inputs.check_output(args.out, "--out", (".json",))  # before the search, not after it
            return _optimize(args, STANCES[args.stance])
        except CmrtError as exc:
            print(f"leg_lift_3d: {exc}", file=sys.stderr)
            return 2
    stance = STANCES[args.stance]
    try:
        curve = _curve(args.cmrt, args.shifts[0])
    except CmrtError as exc:
        parser.error(str(exc))
    if args.filmstrip:
        from cmrt.viz.render3d import filmstrip_3d

        shift = args.shifts[0]
        r, _ = leg_lift_3d(shift_s=shift, lift_s=LIFT_S, clip_s=START_S + shift + LIFT_S + HOLD_S, stance=stance)
        lift_off = START_S + shift
        times = np.array([0.4, START_S + 0.5 * shift, lift_off, lift_off + 0.4 * LIFT_S, lift_off + LIFT_S,
                          lift_off + LIFT_S + HOLD_S - 0.1])
        try:
            done = filmstrip_3d(r, times, args.filmstrip)
        except CmrtError as exc:
            print(f"leg_lift_3d: {exc}", file=sys.stderr)
            return 2
        print(json.dumps(done) if args.json else f"wrote {done['out']}")
        return 0
    rows = [row(s, stance, curve) for s in args.shifts]
    print(json.dumps(rows, indent=1) if args.json else "\n".join(map(_line, rows)))
    return 0


def centre_objective(curve: Cmrt, shift_s: float, stance: int) -> tuple[float, dict]:
    """The centre mode's clip with ``curve``: ``cop_error_objective`` against the support's centre (both feet, the
    stance foot from lift-off), and the clip's row."""
    poses = one_leg_poses(stand_pose_qpos(), stance)
    ch = character("humanoid3d")
    d = mujoco.MjData(ch.model)
    d.qpos[:] = poses.standing
    mujoco.mj_kinematics(ch.model, d)
    both = d.geom_xpos[list(ch.foot_point_geoms), :2].mean(axis=0)
    r, lift_m = leg_lift_3d(shift_s=shift_s, lift_s=LIFT_S, clip_s=curve.clip_s, stance=stance, cmrt_y=curve)
    reference = np.where((r.time_s < START_S + shift_s)[:, None], both, poses.stance_centre_xy_m)
    return cop_error_objective(r, reference), {"success": r.success, "failed_rules": list(r.failed_rules),
                                               "fell": r.fell, "fall_time_s": r.fall_time_s, "foot_lift_m": lift_m,
                                               "max_plan_cop_error_m": r.max_plan_cop_error_m}


def _optimize(args: argparse.Namespace, stance: int) -> int:
    """CMA-ES for the centre mode's CMRT in y (the driver's options and private generator)."""
    shift = args.shifts[0]
    clip_s = START_S + shift + LIFT_S + 1.0
    zero_value, zero_row = centre_objective(Cmrt.zero(clip_s), shift, stance)
    es = new_state(OptimizeSettings(seed=args.seed, popsize=POPSIZE, sigma0=SIGMA0)).es  # the driver's search
    best, evaluations, first_success = (zero_value, Cmrt.zero(clip_s), zero_row), 0, None
    while evaluations < args.optimize:
        xs = es.ask()
        values = []
        for x in xs:
            curve = Cmrt.from_params(np.asarray(x), clip_s)
            value, clip = centre_objective(curve, shift, stance)
            evaluations += 1
            values.append(value)
            if clip["success"] and first_success is None:
                first_success = evaluations
            if value < best[0]:
                best = (value, curve, clip)
        es.tell(xs, values)
    record = {"cmrt": best[1].to_dict(), "clip": best[2], "objective": best[0], "objective_zero": zero_value,
              "zero_clip": zero_row, "evaluations": evaluations, "first_success_evaluation": first_success,
              "what": f"tools/leg_lift_3d.py --shifts {shift} --stance {args.stance} --optimize {args.optimize} "
                      f"--seed {args.seed}: the CMRT in y of the 3D leg lift in the paper's centre mode",
              "found_by": f"CMA-ES (pycma, the driver's options and private generator) from the zero CMRT, sigma "
                          f"{SIGMA0}, population {POPSIZE}, seed {args.seed}; cop_error_objective"}
    if args.out:
        with inputs.atomic_output(args.out, "--out", (".json",)) as tmp:
            Path(tmp).write_text(json.dumps(record, indent=1) + "\n")
    print(json.dumps(record, indent=1) if args.json else
          f"best objective {best[0]:.3f} (zero CMRT {zero_value:.3f}) after {evaluations} evaluations; "
          f"{'a success' if best[2]['success'] else 'not: ' + ', '.join(best[2]['failed_rules'])}")
    return 0


def _line(r: dict) -> str:
    """One row as text."""
    fall = f", fell at {r['fall_time_s']:.2f} s (lift-off {r['lift_off_s']:.2f} s)" if r["fell"] else ""
    return (f"shift {r['shift_s']:.2f} s: {'success' if r['success'] else 'not: ' + ', '.join(r['failed_rules'])}"
            f"{fall}; foot up {100 * r['foot_lift_m']:.1f} cm, CoM at lift-off y "
            f"{100 * r['com_at_lift_off_m'][1]:+.1f} cm")


if __name__ == "__main__":
    raise SystemExit(main())
