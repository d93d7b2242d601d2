"""Directed steps measured (docs/stepping.md): footstep plans of a grid of step lengths and durations, a longer
plan, and thorax pushes during it.

    python tools/stepping_table.py [--json] [--lengths 0.2,0.3,0.4] [--durations 0.4,0.6] [--steps N]
                                   [--pushes 100,150,-50] [--push-times 1.5,2.0,2.5]

* **Plans**: for every step length L and duration T of the grid, two steps forward from standing (``R:+L:T,
  L:+2L:T``), and a long plan: the ``walk`` task as shipped, or with ``--steps N`` N steps of the first length and
  the longest duration, the last bringing the trailing foot beside the leading one. Per plan: success, whether it
  was performed (every step within
  ``FOOTSTEP_TOLERANCE_M`` of its target), the largest placement error, the peak ground force in the 0.1 s after
  any touchdown (body weights), the fastest a landing foot's heel or toe came down just before it landed (m/s),
  how late the latest touchdown came after its planned duration, and how far the thorax pitched (degrees in the
  world, negative forward; a walking person keeps it within a few).
* **Pushes**: the long plan with a 0.1 s thorax push of each force at each start time: success, survived (no
  fall, the plan not carried out) or fell, and how many steps were taken (more than planned: the supervisor
  stepped on its own).
* **Yu's tracked walk** (``yu-walk``): its keyed gait re-keyed with every step length and swing time of the grid,
  at the shallowest crouch the legs reach it with (none: reported refused, with why), and its own gait pushed as
  the long plan is. The same figures; the gait takes a push by moving its swing's landing (cmrt.control.gait), never
  by a step sooner than keyed.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time

import numpy as np

from cmrt import CmrtError, evaluate, resolve_task
from cmrt.body.character import character
from cmrt.motion.footsteps import PlannedStep, plan_text, timeline
from cmrt.sim.simulate import simulate

TOUCHDOWN_SAMPLES = 5  # the landing foot's descent speed is read over this many recorded steps before it
GAIT_CROUCHES_M = (0.03, 0.045, 0.06, 0.08)  # the pelvis lower while walking, tried in turn (yu-walk's is 0.03)
GAIT_PUSHED = (0.2, 0.6)  # the step length (m) and swing (s) of the Yu walk that is pushed (yu-walk's own)
SETTLE_S = 1.5  # the clip lasts this long after the plan's last step is due to land


def two_steps(length_m: float, duration_s: float) -> tuple[PlannedStep, ...]:
    return PlannedStep(0, length_m, duration_s), PlannedStep(1, 2.0 * length_m, duration_s)


def long_plan(n_steps: int, length_m: float, duration_s: float) -> tuple[PlannedStep, ...]:
    """``n_steps`` - 1 alternating steps of ``length_m``, then the trailing foot beside the leading one."""
    walk = [PlannedStep(i % 2, (i + 1) * length_m, duration_s) for i in range(n_steps - 1)]
    return (*walk, PlannedStep((n_steps - 1) % 2, (n_steps - 1) * length_m, duration_s))


def _clip_s(plan: tuple[PlannedStep, ...]) -> float:
    return timeline(plan)[-1][1] + SETTLE_S


def run_plan(plan: tuple[PlannedStep, ...] | None, push_n: float = 0.0, push_start_s: float = 0.0) -> dict:
    """One clip of ``stand`` with this plan (and push), or of the ``walk`` task as shipped (``plan`` None): its
    verdict and figures."""
    params = {"push_force_n": push_n, "push_start_s": push_start_s, "push_duration_s": 0.1}
    if plan is None:
        task = resolve_task("walk", params=params)
        plan = task.plan
    else:
        task = resolve_task("stand", params={**params, "clip_s": round(_clip_s(plan), 2)}, steps=plan)
    return {"plan": plan_text(plan), **_figures(task, [s.duration_s for s in plan], push_n, push_start_s)}


def run_gait(length_m: float, swing_s: float, push_n: float = 0.0, push_start_s: float = 0.0) -> dict:
    """One clip of Yu's tracked walk (``yu-walk``) keyed with this step length and swing time (and push), at the
    shallowest of ``GAIT_CROUCHES_M`` whose keyed legs reach every footprint (longer steps need a lower pelvis)."""
    for crouch in GAIT_CROUCHES_M:
        try:
            task = resolve_task("yu-walk", params={"gait_step_length_m": length_m, "gait_swing_s": swing_s,
                                                   "gait_crouch_m": crouch})
            break
        except CmrtError:
            if crouch == GAIT_CROUCHES_M[-1]:
                raise
    params = {"clip_s": round(task.gait.end_s + SETTLE_S, 2), "push_force_n": push_n, "push_start_s": push_start_s,
              "push_duration_s": 0.1}
    task = task.with_params(**params)
    gait = f"{task.gait.steps} x {length_m:g} m, {swing_s:g} s swings, {crouch * 100:g} cm crouch"
    return {"gait": gait, "crouch_m": crouch,
            **_figures(task, [swing_s] * task.gait.n_steps, push_n, push_start_s)}


def _refused_or(run, length_m: float, swing_s: float, *push) -> dict:
    """``run``'s row, or a row saying why the gait was refused (a step the legs cannot reach)."""
    try:
        return run(length_m, swing_s, *push)
    except CmrtError as exc:
        gait = f"{length_m:g} m, {swing_s:g} s swings"
        return {"gait": gait, "outcome": "refused", "reason": str(exc).removeprefix("--set: gait: ")}


def _figures(task, durations: list[float], push_n: float, push_start_s: float) -> dict:
    """The verdict and figures of one clip of ``task`` whose steps are planned to take ``durations``."""
    traj = simulate(task)
    e = evaluate(task, traj)
    late, speeds = [], []
    for (foot, landed_s, _), lift_s in zip(traj.footprints, traj.step_times_s, strict=False):
        late.append(landed_s - lift_s)
        k = int(np.searchsorted(traj.time_s, landed_s))  # the landing foot's heel and toe coming down before it
        lift = traj.point_lift_m[max(k - TOUCHDOWN_SAMPLES, 0) : k, 2 * foot : 2 * foot + 2]
        if len(lift) > 1:
            speeds.append(float(np.max(-np.diff(lift, axis=0))) / float(traj.time_s[1] - traj.time_s[0]))
    before = slice(None) if traj.fall_time_s is None else traj.time_s < traj.fall_time_s
    # the thorax's pitch in the world: + forward (a +y rotation tips the head toward +x), standing +3.3
    thorax = np.degrees(traj.qpos[before, 2] + traj.qpos[before, character().dof("lumbar")])
    return {
        "push_n": push_n, "push_start_s": push_start_s,
        "outcome": "success" if e.success else ("fell" if e.fell else "survived"),
        "failed_rules": list(e.failed_rules),  # which rules of the one verdict (docs/physics.md) the clip breaks
        "success": e.success, "performed": e.performed, "fell": e.fell, "steps": e.steps,
        "planned_steps": len(durations), "footsteps_landed": e.footsteps_landed,
        "max_footstep_error_m": e.max_footstep_error_m,
        "peak_touchdown_force_bw": e.max_touchdown_force_bw,  # within 0.1 s of a touchdown, before any fall
        "max_touchdown_speed_m_s": max(speeds) if speeds else None,
        # without a push every step is the plan's, in order: how much longer than planned each took to land
        "max_timing_error_s": (max(d - p for d, p in zip(late, durations, strict=False))
                               if late and push_n == 0.0 and e.steps == len(durations) else None),
        "thorax_most_forward_deg": float(thorax.max()) if thorax.size else None,
        "thorax_most_backward_deg": float(thorax.min()) if thorax.size else None,
        "peak_normal_force_bw": e.peak_normal_force_bw, "airborne_s": e.airborne_s,
        "max_foot_slip_m": e.max_foot_slip_m,  # the farthest a heel or toe point slid while touching the floor
        "min_stance_cop_roll": e.min_stance_cop_roll, "walk_speed_m_s": e.walk_speed_m_s,
    }


def _numbers(text: str, what: str, lo: float, hi: float) -> list[float]:
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise CmrtError(f"--{what} must be comma-separated numbers, got {text!r}") from None
    if not values or not all(lo <= abs(v) <= hi for v in values):
        raise CmrtError(f"--{what} must be numbers of size {lo:g} to {hi:g}, got {text!r}")
    return values


def _cells(r: dict) -> tuple[str, str, str, str]:
    """A row's placement error, peak touchdown force, touchdown speed and thorax range as table cells."""
    err = "-" if r["max_footstep_error_m"] is None else f"{r['max_footstep_error_m'] * 1000:.1f}"
    peak = "-" if r["peak_touchdown_force_bw"] is None else f"{r['peak_touchdown_force_bw']:.2f}"
    speed = "-" if r["max_touchdown_speed_m_s"] is None else f"{r['max_touchdown_speed_m_s']:.2f}"
    return err, peak, speed, f"{r['thorax_most_backward_deg']:.0f} to {r['thorax_most_forward_deg']:+.0f}"


def _verdict(r: dict) -> str:
    """The outcome as a cell: success, fell, or stood up and which rules of the one verdict the clip broke."""
    if r["outcome"] == "survived" and r.get("failed_rules"):
        return f"stood; not: {', '.join(r['failed_rules'])}"
    return r["outcome"]


def _push_table(title: str, steps: str, rows: list[dict]) -> None:
    print()
    print(f"| {title} | starts (s) | outcome | {steps} |")
    print("|---|---|---|---|")
    for r in rows:
        print(f"| {r['push_n']:+g} | {r['push_start_s']:g} | {_verdict(r)} | {r.get('steps')} "
              f"({r.get('planned_steps')}) |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lengths", default="0.2,0.3,0.4", help="step lengths, m")
    ap.add_argument("--durations", default="0.4,0.6", help="step durations, s")
    ap.add_argument("--steps", type=int, default=None,
                    help="steps of a uniform long plan (its last brings the feet together; default: the walk task)")
    ap.add_argument("--pushes", default="100,150,-50", help="thorax pushes during the long plan, N (0.1 s each)")
    ap.add_argument("--push-times", default="1.5,2.0,2.5", help="when they start, s")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    try:
        lengths = _numbers(args.lengths, "lengths", 0.05, 0.45)
        durations = _numbers(args.durations, "durations", 0.3, 1.5)
        pushes = _numbers(args.pushes, "pushes", 0.0, 1000.0) if args.pushes else []
        times = _numbers(args.push_times, "push-times", 0.0, 30.0)
        if args.steps is not None and not 2 <= args.steps <= 30:
            raise CmrtError(f"--steps must be 2 to 30, got {args.steps}")
        if any(v <= 0 for v in lengths):
            raise CmrtError("--lengths are forward steps: positive")
        start = time.perf_counter()
        plans = [run_plan(two_steps(length, duration)) for length in lengths for duration in durations]
        longest = None if args.steps is None else long_plan(args.steps, lengths[0], max(durations))
        plans.append(run_plan(longest))
        pushed = [run_plan(longest, force, at) for force in pushes for at in times]
        gaits = [_refused_or(run_gait, length, duration) for length in lengths for duration in durations]
        gait_pushes = [_refused_or(run_gait, GAIT_PUSHED[0], GAIT_PUSHED[1], force, at)
                       for force in pushes for at in times]
    except CmrtError as exc:
        print(f"stepping_table: error: {exc}", file=sys.stderr)
        return 2
    out = {"machine": platform.machine(), "python": platform.python_version(),
           "wall_s": round(time.perf_counter() - start, 1), "plans": plans, "pushes": pushed, "gaits": gaits,
           "gait_pushes": gait_pushes}
    if args.json:
        print(json.dumps(out, indent=1, allow_nan=False, default=lambda v: None))
        return 0
    print("| plan | outcome | placement error (mm) | peak touchdown force (BW) | touchdown speed (m/s) "
          "| latest landing (s late) | thorax (deg) | slip (cm) | heel-to-toe roll | walking speed (m/s) |")
    print("|---|---|---|---|---|---|---|---|---|---|")  # thorax: its pitch's range, most backward to most forward
    for r in plans:
        late = "-" if r["max_timing_error_s"] is None else f"{r['max_timing_error_s']:.3f}"
        err, peak, speed, thorax = _cells(r)
        slip = "-" if r["max_foot_slip_m"] is None else f"{r['max_foot_slip_m'] * 100:.2f}"
        roll = "-" if r["min_stance_cop_roll"] is None else f"{r['min_stance_cop_roll']:.2f}"
        pace = "-" if r["walk_speed_m_s"] is None else f"{r['walk_speed_m_s']:.2f}"
        print(f"| `{r['plan']}` | {_verdict(r)} | {err} | {peak} | {speed} | {late} | {thorax} | {slip} | {roll} "
              f"| {pace} |")
    _push_table("push (N)", "steps (planned)", pushed)
    print()
    print("| Yu's tracked walk | outcome | placement error (mm) | peak touchdown force (BW) | touchdown speed (m/s) "
          "| thorax (deg) |")
    print("|---|---|---|---|---|---|")
    for r in gaits:
        if r["outcome"] == "refused":
            print(f"| {r['gait']} | refused: {r['reason']} | - | - | - | - |")
        else:
            print(f"| {r['gait']} | {_verdict(r)} | {' | '.join(_cells(r))} |")
    _push_table("push on Yu's walk (N)", "steps (keyed)", gait_pushes)
    print(f"\n{out['wall_s']} s on {out['machine']}, Python {out['python']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
