"""How reliably does ``cmrt optimize`` find a successful CMRT? One run per seed, default settings.

    python tools/success_rate.py bend --speed 0.4 --seeds 1-10 [--init none|auto] [--json]

Each seed is a full optimization (batched evaluator, the default budget and stopping rules)
into a scratch store of its own; a seed succeeds when its best CMRT is a success (balance held, motion
performed, settled, goal reached). Reports the success rate, the evaluations until the first
successful candidate (median and worst over the seeds that found one), the fraction of seeds whose best
is a success below the task's ``stop_threshold`` (``under_threshold_rate``), restarts and wall time.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

from cmrt import CmrtError, Evaluator, open_store, optimize_now, resolve_task
from cmrt.inputs import parse_sets


def parse_seeds(text: str) -> list[int]:
    seeds: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        seeds.extend(range(int(lo), int(hi or lo) + 1))
    if not seeds:
        raise CmrtError("--seeds: give seeds like 1-10 or 1,3,5")
    return seeds


def first_success(store, run_id: int) -> int | None:
    """Evaluations done up to and including the first successful candidate."""
    for n, e in enumerate(store.evaluations(run_id), start=1):
        if e.success:
            return n
    return None


def measure(task, seeds: list[int], init: str, max_evals: int, progress: bool) -> dict:
    rows = []
    with tempfile.TemporaryDirectory() as tmp, Evaluator("batch") as ev:
        for seed in seeds:  # a fresh store per seed: seeds are independent (auto starts from the library)
            t0 = time.perf_counter()
            with open_store(Path(tmp) / f"seed{seed}.sqlite") as store:
                run = optimize_now(store, task, ev, seed=seed, init=init, max_evals=max_evals)
                first = first_success(store, run.id)
            rows.append({
                "seed": seed, "success": bool(run.best_success), "best_objective": run.best_objective,
                "evaluations": run.evaluations, "first_success_evals": first,
                "restarts": run.restarts, "stop_reason": run.stop_reason, "init": run.init_source,
                "wall_s": round(time.perf_counter() - t0, 1),
            })
            if progress:
                print(json.dumps(rows[-1]), file=sys.stderr)
    return summary(task, seeds, init, max_evals, rows)


def summary(task, seeds: list[int], init: str, max_evals: int, rows: list[dict]) -> dict:
    """The figures over the seeds' rows (dicts, as ``measure`` builds them and ``--json`` prints them).
    ``under_threshold_rate``: seeds whose best is a success below the task's ``stop_threshold`` - the runs
    that stopped on the threshold rule rather than converging or running out of budget above it."""
    found = [r["first_success_evals"] for r in rows if r["success"]]
    under = [r["success"] and r["best_objective"] < task.stop_threshold for r in rows]
    return {
        "task": task.name, "speed": task.speed, "init": init, "seeds": seeds, "max_evals": max_evals,
        "stop_threshold": task.stop_threshold,
        "success_rate": sum(r["success"] for r in rows) / len(rows),
        "under_threshold_rate": sum(under) / len(rows),
        "median_evals_to_success": statistics.median(found) if found else None,
        "worst_evals_to_success": max(found) if found else None,
        "wall_s": round(sum(r["wall_s"] for r in rows), 1),
        "machine": f"{platform.machine()}, {__import__('os').cpu_count()} cores, Python {platform.python_version()}",
        "runs": rows,
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("task")
    p.add_argument("--speed", type=float)
    p.add_argument("--set", action="append", metavar="KEY=VALUE")
    p.add_argument("--seeds", default="1-10")
    p.add_argument("--init", default="none", choices=("none", "auto"))
    p.add_argument("--max-evals", type=int, default=3000)
    p.add_argument("--json", action="store_true")
    p.add_argument("--quiet", action="store_true", help="no per-seed lines on stderr")
    args = p.parse_args()
    try:
        task = resolve_task(args.task, args.speed, parse_sets(args.set))
        result = measure(task, parse_seeds(args.seeds), args.init, args.max_evals, not args.quiet)
    except (CmrtError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(result))
    else:
        speed = f" --speed {task.speed:g}" if task.speed is not None else ""
        print(f"{task.name}{speed}, init {args.init}: {result['success_rate']:.0%} of {len(result['seeds'])} seeds "
              f"({result['under_threshold_rate']:.0%} below the threshold {task.stop_threshold:g}); "
              f"evaluations to the first success: median {result['median_evals_to_success']}, worst "
              f"{result['worst_evals_to_success']}; {result['wall_s']} s")
        for r in result["runs"]:
            print(f"  seed {r['seed']}: {'success' if r['success'] else 'FAILED '} objective {r['best_objective']:.3f} "
                  f"after {r['evaluations']} evals ({r['stop_reason']}, {r['restarts']} restarts), {r['wall_s']} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
