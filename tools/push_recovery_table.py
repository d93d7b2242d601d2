"""The largest 0.1 s thorax push (forward and backward) the character survives, per supervisor: standing
balance alone (stepping=0), the momentum supervisor (1) and its capture-point variant (2) - the
push-recovery table of docs/results/stepping.md (Wu and Zordan 2010 report 170 N routinely and 250 N for
the momentum supervisor where the inverted-pendulum variant fails).

A push survives if the clip is a success (balance kept and standing still at the end of the tail). The
largest surviving force is found by bisection on [0, --max-force] to --resolution newtons; survival is
not guaranteed to be monotone in the force, so every force tried is reported too.

    python tools/push_recovery_table.py [--json] [--max-force 400] [--resolution 10]
"""

from __future__ import annotations

import argparse
import json
import time

from cmrt import evaluate, load_task, simulate
from cmrt.control.stepping import RULES

SUPERVISORS = {0: "standing (no stepping)", **{k: f"{v} supervisor" for k, v in RULES.items()}}


def trial(stepping: int, force_n: float) -> dict:
    """One push-recovery clip: the push's outcome and the steps it took."""
    task = load_task("push-recovery").with_params(stepping=stepping, push_force_n=force_n, push_duration_s=0.1)
    traj = simulate(task, None, record=False)
    ev = evaluate(task, traj)
    return {"force_n": force_n, "success": ev.success, "steps": ev.steps, "fall_reason": ev.fall_reason,
            "peak_normal_force_bw": round(ev.peak_normal_force_bw, 2)}


def largest(stepping: int, sign: int, max_force: float, resolution: float) -> dict:
    """Bisection for the largest surviving push magnitude in direction ``sign``."""
    tried = []
    lo, hi = 0.0, max_force
    top = trial(stepping, sign * hi)
    tried.append(top)
    best = top if top["success"] else None
    if best is None:
        while hi - lo > resolution:
            mid = round(0.5 * (lo + hi) / resolution) * resolution
            if mid in (lo, hi):
                break
            r = trial(stepping, sign * mid)
            tried.append(r)
            if r["success"]:
                lo, best = mid, r
            else:
                hi = mid
    return {"supervisor": SUPERVISORS[stepping], "stepping": stepping,
            "direction": "forward" if sign > 0 else "backward",
            "largest_push_survived_n": best["force_n"] if best else None,
            "steps_at_largest": best["steps"] if best else None,
            "peak_normal_force_bw_at_largest": best["peak_normal_force_bw"] if best else None,
            "tried": sorted(tried, key=lambda r: abs(r["force_n"]))}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", action="store_true")
    p.add_argument("--max-force", type=float, default=400.0)
    p.add_argument("--resolution", type=float, default=10.0)
    args = p.parse_args()
    t0 = time.perf_counter()
    rows = [largest(s, sign, args.max_force, args.resolution) for s in SUPERVISORS for sign in (1, -1)]
    if args.json:
        print(json.dumps({"rows": rows, "wall_s": round(time.perf_counter() - t0, 1)}, indent=1))
        return
    print("| supervisor | direction | largest 0.1 s push survived (N) | steps taken |")
    print("|---|---|---|---|")
    for r in rows:
        force = "-" if r["largest_push_survived_n"] is None else f"{abs(r['largest_push_survived_n']):.0f}"
        print(f"| {r['supervisor']} | {r['direction']} | {force} | {r['steps_at_largest'] or 0} |")


if __name__ == "__main__":
    main()
