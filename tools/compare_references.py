"""Reactive reference (Yu) vs anticipation (CMRT), side by side: the comparison table of docs/results/references.md.

    python tools/compare_references.py [--json] [--tasks fast-bend,punch] [--pushes 100,150,200,250,300,400]
                                       [--optimize] [--max-evals 1500] [--push-max-evals 600] [--seed 1]

For every task (fast bend T = 0.4 s, slow bend T = 1.2 s, punch, catch, push) and standing thorax pushes
(0.1 s, both directions), four controllers: the zero CMRT and an optimized CMRT, each with the
``center`` reference (the support centre; ABC) and with ``yu`` (GRF-weighted feet and Winter's CoP,
``cmrt.control.references``). Each optimized CMRT is optimized on its own mode. Per row: success,
objective (the paper's: CoP error against the support centre, plus penalties - one scale for both modes),
the CoP error against the mode's own reference CoP, the smallest CoP margin and why a failure failed.

Where the CMRTs come from: for the tasks, the library's entry for the mode (``tools/find_library_curve.py
--reference MODE``: seed 1, 1500 evaluations) unless ``--optimize`` re-optimizes them here; for the pushes
(not in the library) a run of ``--push-max-evals`` evaluations, only where the zero CMRT fails (a push the
reactive controller survives needs no anticipation). "Largest push survived": the zero CMRT swept in 5 N
steps (one batch per mode and direction); the optimized CMRT over the ``--pushes`` grid.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from cmrt import (
    CmrtError,
    Evaluator,
    Perturbation,
    evaluate,
    library_curve,
    load_task,
    open_store,
    optimize_now,
    run_curve,
    simulate,
)
from cmrt.modes import REFERENCE_MODES
from cmrt.sim.simulate import simulate_batch

TASKS = {
    "fast-bend": ("bend", {"duration_s": 0.4}),
    "slow-bend": ("bend", {"duration_s": 1.2}),
    "punch": ("punch", {}),
    "catch": ("catch", {}),
    "push": ("push", {}),
}
# a standing push: 1.5 s of standing, the push, 2.5 s to recover (the balance monitor declares a topple
# within ~1.3 s of a push: docs/controller.md), then the 0.5 s standing tail
PUSH_CLIP = {"clip_s": 4.0, "push_start_s": 1.5, "push_duration_s": 0.1}
SWEEP_STEP_N = 5.0
SWEEP_MAX_N = 400.0


def _row(label: str, task, curve_kind: str, curve, source: str) -> dict:
    ev = evaluate(task, simulate(task, curve, record=False))
    return {"task": label, "reference": task.reference_mode, "curve": curve_kind, "source": source,
            "success": ev.success, "objective": ev.objective, "cop_error_norm": ev.cop_error_norm,
            "cop_error_own_reference_norm": ev.cop_error_own_reference_norm,
            "min_cop_margin_m": ev.min_cop_margin_m, "fell": ev.fell, "fall_reason": ev.fall_reason,
            "performed": ev.performed, "tracking_error_rad": ev.tracking_error_rad,
            "failed_rules": list(ev.failed_rules)}


def _optimized(task, seed: int, max_evals: int, use_library: bool):
    """(CMRT optimized on the task's own reference mode, where it came from)."""
    if use_library:
        try:
            return library_curve(task), "library"
        except CmrtError:
            pass
    with tempfile.TemporaryDirectory() as tmp, open_store(Path(tmp) / "cmp.sqlite") as store, \
            Evaluator("batch") as evaluator:
        run = optimize_now(store, task, evaluator, seed=seed, max_evals=max_evals, init="none")
        return run_curve(store, run.id), f"optimized (seed {seed}, {run.evaluations} evaluations)"


def _largest_zero_push(mode: str, sign: float) -> float:
    """The largest push (N, in 5 N steps) the zero CMRT survives with this reference, from one batch."""
    forces = np.arange(SWEEP_STEP_N, SWEEP_MAX_N + 1e-9, SWEEP_STEP_N)
    task = load_task("stand").with_params(**PUSH_CLIP, push_force_n=0.0).with_reference(mode)
    members = [Perturbation(push_force_n=sign * f, push_start_s=PUSH_CLIP["push_start_s"],
                            push_duration_s=PUSH_CLIP["push_duration_s"]) for f in forces]
    ok = [evaluate(task, t).success for t in simulate_batch(task, [None] * len(forces), perturbations=members)]
    survived = [f for f, s in zip(forces, ok, strict=True) if s]
    return float(max(survived)) if survived else 0.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--tasks", default=",".join(TASKS), help=f"comma-separated subset of {','.join(TASKS)}")
    ap.add_argument("--pushes", default="100,150,200,250,300,400", help="push forces (N, both directions; '' for none)")
    ap.add_argument("--optimize", action="store_true", help="re-optimize the tasks' CMRTs instead of the library's")
    ap.add_argument("--max-evals", type=int, default=1500)
    ap.add_argument("--push-max-evals", type=int, default=600)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    labels = [t for t in args.tasks.split(",") if t]
    unknown = [t for t in labels if t not in TASKS]
    if unknown:
        ap.error(f"--tasks: unknown {', '.join(unknown)} (known: {', '.join(TASKS)})")
    pushes = [float(p) for p in args.pushes.split(",") if p.strip()]

    rows: list[dict] = []

    def add(row: dict) -> None:
        rows.append(row)
        print(json.dumps(row), file=sys.stderr)

    for label in labels:
        name, params = TASKS[label]
        for mode in REFERENCE_MODES:
            task = load_task(name).with_params(**params).with_reference(mode)
            add(_row(label, task, "zero", None, "zero"))
            curve, source = _optimized(task, args.seed, args.max_evals, not args.optimize)
            add(_row(label, task, "optimized", curve, source))
    largest = []
    for sign in ((1.0, -1.0) if pushes else ()):
        for mode in REFERENCE_MODES:
            best_optimized = 0.0
            for force in pushes:
                label = f"stand push {sign * force:+.0f} N"
                task = load_task("stand").with_params(**PUSH_CLIP, push_force_n=sign * force).with_reference(mode)
                zero = _row(label, task, "zero", None, "zero")
                add(zero)
                if zero["success"]:
                    best_optimized = max(best_optimized, force)  # no anticipation needed
                    continue
                curve, source = _optimized(task, args.seed, args.push_max_evals, use_library=False)
                opt = _row(label, task, "optimized", curve, source)
                add(opt)
                if opt["success"]:
                    best_optimized = max(best_optimized, force)
            largest.append({"direction": "forward" if sign > 0 else "backward", "reference": mode,
                            "zero_cmrt_n": _largest_zero_push(mode, sign), "optimized_cmrt_n": best_optimized,
                            "optimized_grid_n": pushes,
                            # the grid's largest push was survived: the limit lies beyond the grid
                            "optimized_at_least": best_optimized == max(pushes)})
            print(json.dumps(largest[-1]), file=sys.stderr)
    if args.json:
        print(json.dumps({"rows": rows, "largest_push": largest}, indent=1))
        return
    print(f"{'task':<22} {'reference':<9} {'curve':<9} {'success':<7} {'objective':>9} {'own CoP err':>11} "
          f"{'min margin cm':>13}  failed rules")
    for r in rows:
        why = ", ".join(r["failed_rules"]) + (f" ({r['fall_reason']})" if r["fall_reason"] else "")
        print(f"{r['task']:<22} {r['reference']:<9} {r['curve']:<9} {str(r['success']):<7} {r['objective']:>9.3f} "
              f"{r['cop_error_own_reference_norm']:>11.3f} {100 * r['min_cop_margin_m']:>13.1f}  {why}")
    for r in largest:
        at_least = ">= " if r["optimized_at_least"] else ""
        print(f"largest {r['direction']} push survived, {r['reference']}: zero CMRT {r['zero_cmrt_n']:.0f} N, "
              f"optimized CMRT {at_least}{r['optimized_cmrt_n']:.0f} N (grid {r['optimized_grid_n']})")


if __name__ == "__main__":
    main()
