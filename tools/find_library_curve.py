"""Optimize a task at one speed with the real optimizer and ship the result in the library.

Runs ``cmrt.optimize_now`` (CMA-ES, batched evaluation) into a scratch store and writes
the best CMRT with its provenance to ``cmrt/motion/library.json``, where
``--curve library`` finds it.

    python tools/find_library_curve.py bend --speed 0.4 --seed 1 --max-evals 1500 --stop-threshold 0
    python tools/find_library_curve.py bend --speed 0.4 --reference yu   # for Yu's reactive reference

``--robust`` scores candidates on the task's ensemble (``cmrt.motion.ensemble``); ``--init auto``
starts from the nearest library CMRT (how the shipped robust CMRTs were made: each from
the plain CMRT of its own task, with ``--sigma0 0.15``).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from cmrt import Evaluator, evaluate, load_task, open_store, optimize_now, run_curve, simulate
from cmrt.modes import REFERENCE_MODES
from cmrt.motion.footsteps import plan_text
from cmrt.motion.library import save_entry


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("task")
    ap.add_argument("--speed", type=float)
    ap.add_argument("--speeds", help="a family: comma-separated speeds, each warm-started from the previous")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--max-evals", type=int, default=1500)
    ap.add_argument("--stop-threshold", type=float, help="override the task's (0: run to convergence)")
    ap.add_argument("--backend", default="batch")
    ap.add_argument("--family-sigma0", type=float, default=0.15,
                    help="CMA-ES step size for warm-started family members: stay near the neighbour's solution "
                         "so the family keeps one shape and interpolates (ABC 4.2)")
    ap.add_argument("--robust", action="store_true", help="score candidates on the task's robust ensemble")
    ap.add_argument("--reference", choices=REFERENCE_MODES, default="center",
                    help="the controller's reference mode the CMRT is optimized for (kept apart in the library)")
    ap.add_argument("--init", default="none", choices=("none", "auto"), help="start of the first (or only) run")
    ap.add_argument("--sigma0", type=float, default=0.5, help="step size of the first (or only) run")
    ap.add_argument("--no-save", action="store_true")
    args = ap.parse_args()

    base = load_task(args.task).with_params(**dict(kv.split("=", 1) for kv in args.set))
    if args.stop_threshold is not None:
        base = base.with_params(stop_threshold=args.stop_threshold)
    if args.robust:
        base = base.with_robust()
    base = base.with_reference(args.reference)
    speeds = [float(s) for s in args.speeds.split(",")] if args.speeds else [args.speed]
    with tempfile.TemporaryDirectory() as tmp, open_store(Path(tmp) / "lib.sqlite") as store:
        previous = None
        for speed in speeds:
            task = base.with_speed(speed)
            t0 = time.perf_counter()
            with Evaluator(args.backend) as ev:
                sigma0 = args.sigma0 if previous is None else args.family_sigma0
                run = optimize_now(store, task, ev, seed=args.seed, max_evals=args.max_evals,
                                   init=previous or args.init, sigma0=sigma0)
            previous = run.id
            record(task, run, run_curve(store, run.id), args, time.perf_counter() - t0)


def _check(task, curve) -> dict:
    """The CMRT's clip re-simulated: the figures an entry keeps (a 3D task's with its timing lag)."""
    check = evaluate(task, simulate(task, curve))
    out = {"objective": check.objective, "success": check.success, "fell": check.fell,
           "task_success": check.task_success, "tracking_error_rad": check.tracking_error_rad,
           "min_cop_margin_m": check.min_cop_margin_m, "final_pose_error_rad": check.final_pose_error_rad}
    return out | ({"timing_lag_s": check.timing_lag_s} if task.body != "planar" else {})


def record(task, run, curve, args, wall_s: float) -> None:
    entry = {
        "task": task.name, "speed": task.speed, "cmrt": curve.to_dict(), **_check(task, curve),
        "zero_cmrt_objective": run.baseline_objective, "zero_cmrt_success": run.baseline_success,
        "zero_cmrt_fell": run.baseline_fell,
        "evaluations": run.evaluations, "stop_reason": run.stop_reason, "seed": args.seed,
        "stop_threshold": task.stop_threshold, "wall_s": round(wall_s, 1), "init_run": run.init_run is not None,
        "params": task.params, "robust": task.robust.enabled, "init": run.init_source,
        "restarts": run.restarts, "robustness": run.robustness, "motion": task.motion_hash(),
    }
    if task.reference_mode != "center":  # entries without the key are the center mode's
        entry["reference"] = task.reference_mode
    if task.steps:  # a footstep plan's CMRT belongs to that plan (entries without the key: no plan)
        entry["steps"] = plan_text(task.steps)
    print(json.dumps(entry, indent=2))
    if not args.no_save:
        save_entry(entry)


if __name__ == "__main__":
    main()
