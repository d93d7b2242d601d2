"""A speed family solved together against its members solved alone: evaluations to each member's stop.

    python tools/family_benchmark.py --task bend --speeds 0.4,0.5,0.6,0.8,1.0 --seeds 1-3 [--json]

For each seed: ``cmrt.optimize_family`` (each member after the first warm-started from the previous member's best
with ``FAMILY_SIGMA0``) against each member optimized cold (``init="none"``), both with the task's stopping rules
(the threshold stop on a success below ``stop_threshold``, else the budget). Reports the evaluations each member
took, whether it ended a success, and the family's total over the cold runs' total (the issue's goal: <= 0.5).
Every search of both arms starts the same seed.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
from pathlib import Path

from cmrt import CmrtError, Evaluator, open_store, optimize_family, optimize_now, resolve_task
from cmrt.optimize.settings import FAMILY_SIGMA0


def measure(task_name: str, speeds: list[float], seed: int, max_evals: int, family_sigma0: float) -> dict:
    """One seed: the family's and the cold runs' evaluations and verdicts, per member."""
    tasks = [resolve_task(task_name, s) for s in speeds]
    with tempfile.TemporaryDirectory() as tmp, Evaluator("batch") as ev:
        with open_store(Path(tmp) / "family.sqlite") as store:
            family = optimize_family(store, tasks, ev, family_sigma0=family_sigma0, seed=seed, init="none",
                                     max_evals=max_evals, progress=False)
        with open_store(Path(tmp) / "cold.sqlite") as store:
            cold = [optimize_now(store, t, ev, seed=seed, init="none", max_evals=max_evals, progress=False)
                    for t in tasks]
    row = {"seed": seed, "members": [
        {"speed": s, "family_evals": f.evaluations, "family_success": f.best_success,
         "family_objective": f.best_objective, "cold_evals": c.evaluations, "cold_success": c.best_success,
         "cold_objective": c.best_objective}
        for s, f, c in zip(speeds, family, cold, strict=True)]}
    row["family_total"] = sum(m["family_evals"] for m in row["members"])
    row["cold_total"] = sum(m["cold_evals"] for m in row["members"])
    row["ratio"] = row["family_total"] / row["cold_total"]
    return row


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--task", default="bend")
    p.add_argument("--speeds", default="0.4,0.5,0.6,0.8,1.0")
    p.add_argument("--seeds", default="1-3", help="e.g. 1-3 or 1,4")
    p.add_argument("--max-evals", type=int, default=3000)
    p.add_argument("--family-sigma0", type=float, default=FAMILY_SIGMA0)
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    try:
        speeds = [float(s) for s in args.speeds.split(",")]
        lo, _, hi = args.seeds.partition("-")
        seeds = list(range(int(lo), int(hi or lo) + 1)) if "," not in args.seeds else [
            int(s) for s in args.seeds.split(",")]
        rows = [measure(args.task, speeds, seed, args.max_evals, args.family_sigma0) for seed in seeds]
    except (CmrtError, ValueError) as exc:
        print(f"error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    family, cold = sum(r["family_total"] for r in rows), sum(r["cold_total"] for r in rows)
    out = {"task": args.task, "speeds": speeds, "family_sigma0": args.family_sigma0, "rows": rows,
           "family_total": family, "cold_total": cold, "ratio": family / cold,
           "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"}
    if args.json:
        print(json.dumps(out))
        return 0
    for r in rows:
        members = ", ".join(f"{m['speed']:g}: {m['family_evals']} vs {m['cold_evals']}" for m in r["members"])
        print(f"seed {r['seed']}: family {r['family_total']} vs cold {r['cold_total']} evaluations "
              f"({r['ratio']:.2f}); per speed {members}")
    print(f"all seeds: family {family} vs cold {cold} evaluations: {family / cold:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
