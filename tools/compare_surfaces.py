"""Balance on each support surface, per reference mode, without and with a CMRT (docs/surfaces.md).

    python tools/compare_surfaces.py --json
    python tools/compare_surfaces.py --surfaces level,shaking --modes center --tasks bend --max-evals 100

For every surface (``SURFACES``: the still level floor, Yu's slippery floor, his 15 degree slope, his shaking
plane, a swaying platform, his floating box) and reference mode (``center``, ``yu``), each task of ``--tasks``:

* ``stand``: quiet standing with thorax pushes of 0.1 s, +-F at F = 50, 100, ... N (``--pushes``), both
  directions, in that order until one falls: the largest F survived both ways;
* ``bend`` (the fast bend, 0.4 s), ``slow-bend`` (1.2 s), ``squat``: the zero CMRT, then - where it fails - a
  CMA-ES CMRT optimized on that surface (``cmrt optimize`` with its defaults, ``--max-evals``, seed 1).

One row per surface x mode x task x curve: success, objective, the largest push survived (stand), the farthest
a planted heel or toe slid (``max_foot_slip_m``) and the plausibility figures (peak ground force in body
weights, time airborne, fastest joint).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

from cmrt import CmrtError, evaluate, open_store, optimize_now, resolve_task, run_curve
from cmrt.sim.simulate import simulate

SURFACES: dict[str, dict[str, float]] = {
    "level": {},
    "slippery": {"floor_friction": 0.08},  # Yu: 0.08 against 0.8
    "slope": {"slope_deg": 15.0},
    "shaking": {"tilt_amplitude_deg": 20.0, "tilt_period_s": 2.0},  # Yu: -20 to +20 degrees
    "swaying": {"sway_amplitude_m": 0.05, "sway_period_s": 1.0},
    "floating": {"box_mass_kg": 200.0},  # Yu's floating box: 200 kg on water of 9.81 kN/m (cmrt.body.floating_box)
}
TASKS: dict[str, tuple[str, dict[str, float]]] = {
    "stand": ("stand", {"clip_s": 4.0}),  # the push at 2 s, 2 s to recover, then the tail
    "bend": ("bend", {"duration_s": 0.4}),
    "slow-bend": ("bend", {"duration_s": 1.2}),
    "squat": ("squat", {}),
}
PUSHES_N = (50.0, 100.0, 150.0, 200.0, 250.0)


def _row(surface: str, mode: str, name: str, curve: str, e, extra: dict | None = None) -> dict:
    return {"surface": surface, "mode": mode, "task": name, "curve": curve, "success": e.success,
            "objective": round(e.objective, 4), "fell": e.fell, "max_foot_slip_m": e.max_foot_slip_m,
            "peak_normal_force_bw": round(e.peak_normal_force_bw, 3), "airborne_s": e.airborne_s,
            "max_joint_speed_rad_s": round(e.max_joint_speed_rad_s, 2), **(extra or {})}


def _evaluate(task, curve=None):
    return evaluate(task, simulate(task, curve))


def largest_push(task, pushes_n) -> tuple[float, object]:
    """The largest push survived both ways (0: the smallest already fells it) and the evaluation of that push."""
    best, best_eval = 0.0, _evaluate(task)
    for force in pushes_n:
        evals = [_evaluate(task.with_params(push_force_n=sign * force)) for sign in (1.0, -1.0)]
        if not all(e.success for e in evals):
            break
        best, best_eval = force, max(evals, key=lambda e: e.max_foot_slip_m or 0.0)
    return best, best_eval


def compare(surfaces: list[str], modes: list[str], tasks: list[str], max_evals: int, pushes_n) -> list[dict]:
    rows = []
    for surface in surfaces:
        for mode in modes:
            for name in tasks:
                base, params = TASKS[name]
                task = resolve_task(base, params={**params, **SURFACES[surface]}, reference=mode)
                if name == "stand":
                    force, e = largest_push(task, pushes_n)
                    rows.append(_row(surface, mode, name, "zero", e, {"largest_push_n": force}))
                    continue
                zero = _evaluate(task)
                rows.append(_row(surface, mode, name, "zero", zero))
                if zero.success or max_evals <= 0:
                    continue
                with tempfile.TemporaryDirectory() as tmp, open_store(Path(tmp) / "s.sqlite") as store:
                    run = optimize_now(store, task, seed=1, max_evals=max_evals)
                    curve = run_curve(store, run.id)
                rows.append(_row(surface, mode, name, "cmrt", _evaluate(task, curve),
                                 {"evaluations": run.evaluations}))
    return rows


def _names(text: str, known, what: str) -> list[str]:
    names = [s.strip() for s in text.split(",") if s.strip()]
    bad = [n for n in names if n not in known]
    if bad or not names:
        raise CmrtError(f"unknown {what} {', '.join(bad) or '(none given)'}: choose from {', '.join(known)}")
    return names


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--surfaces", default=",".join(SURFACES), help=f"default: {','.join(SURFACES)}")
    ap.add_argument("--modes", default="center,yu", help="reference modes (default: center,yu)")
    ap.add_argument("--tasks", default=",".join(TASKS), help=f"default: {','.join(TASKS)}")
    ap.add_argument("--max-evals", type=int, default=300, help="CMA-ES budget where the zero CMRT fails "
                    "(0: no CMRT rows; default: 300)")
    ap.add_argument("--pushes", default=",".join(f"{p:g}" for p in PUSHES_N),
                    help="push forces tried, N, ascending (default: %(default)s)")
    ap.add_argument("--json", action="store_true", help="print the rows as JSON")
    args = ap.parse_args(argv)
    try:
        surfaces = _names(args.surfaces, SURFACES, "surface")
        modes = _names(args.modes, ("center", "yu"), "mode")
        tasks = _names(args.tasks, TASKS, "task")
        pushes = [float(p) for p in args.pushes.split(",")]
        if args.max_evals < 0 or any(p <= 0 for p in pushes) or pushes != sorted(pushes):
            raise CmrtError("--max-evals must be >= 0 and --pushes positive and ascending")
    except (CmrtError, ValueError) as exc:
        print(f"compare_surfaces: {exc}", file=sys.stderr)
        return 2
    t0 = time.time()
    rows = compare(surfaces, modes, tasks, args.max_evals, pushes)
    if args.json:
        print(json.dumps({"machine": platform.machine(), "python": platform.python_version(),
                          "wall_s": round(time.time() - t0, 1), "rows": rows}, indent=1))
        return 0
    print("| surface | mode | task | curve | success | objective | largest push N | slip mm | peak BW |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        slip = "-" if r["max_foot_slip_m"] is None else f"{1000 * r['max_foot_slip_m']:.1f}"
        print(f"| {r['surface']} | {r['mode']} | {r['task']} | {r['curve']} | {'yes' if r['success'] else 'no'} | "
              f"{r['objective']:.3f} | {r.get('largest_push_n', '-')} | {slip} | {r['peak_normal_force_bw']:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
