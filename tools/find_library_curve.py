"""Find a CMRT that balances a task at one speed and ship it in the library.

A plain CMA-ES search (pycma ask/tell, serial) over the 8 curve parameters, started
from the flat spline. The full optimization service (store, jobs, resume, parallel
backends) is `cmrt optimize`; this script exists so the foundation can ship a
library curve and show that a rescue exists.

    python tools/find_library_curve.py bend --speed 0.4 --seed 1 --max-evals 700
"""

from __future__ import annotations

import argparse
import json
import time

import cma
import numpy as np

from cmrt import Cmrt, evaluate, load_task, simulate
from cmrt.library import save_entry


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("task")
    ap.add_argument("--speed", type=float)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--max-evals", type=int, default=700)
    ap.add_argument("--popsize", type=int, default=10)
    ap.add_argument("--sigma0", type=float, default=0.5)
    ap.add_argument("--no-save", action="store_true")
    args = ap.parse_args()

    task = load_task(args.task).with_speed(args.speed)
    zero = evaluate(task, simulate(task))
    rng = np.random.default_rng(args.seed)
    # seed=nan + our own randn: pycma must not touch numpy's global RNG.
    opts = {
        "popsize": args.popsize,
        "seed": np.nan,
        "randn": lambda *s: rng.standard_normal(s),
        "verbose": -9,
        "maxfevals": args.max_evals,
        "verb_log": 0,
        "verb_disp": 0,
    }
    es = cma.CMAEvolutionStrategy(np.zeros(8), args.sigma0, opts)
    best_u, best = None, None
    n, t0 = 0, time.perf_counter()
    while not es.stop() and n < args.max_evals:
        xs = es.ask()
        evs = [evaluate(task, simulate(task, Cmrt.from_params(x, task.clip_s))) for x in xs]
        es.tell(xs, [e.objective for e in evs])
        n += len(xs)
        i = int(np.argmin([e.objective for e in evs]))
        if best is None or evs[i].objective < best.objective:
            best_u, best = np.array(xs[i]), evs[i]
        print(
            f"evals {n:4d}  best {best.objective:.4f}  fell {best.fell}  sigma {es.sigma:.3f}  "
            f"{time.perf_counter() - t0:.0f} s",
            flush=True,
        )
    curve = Cmrt.from_params(best_u, task.clip_s)
    entry = {
        "task": task.name,
        "speed": task.speed,
        "cmrt": curve.to_dict(),
        "objective": best.objective,
        "fell": best.fell,
        "final_pose_error_rad": best.final_pose_error_rad,
        "zero_cmrt_objective": zero.objective,
        "zero_cmrt_fell": zero.fell,
        "evaluations": n,
        "seed": args.seed,
        "search": f"CMA-ES popsize {args.popsize} sigma0 {args.sigma0}",
        "wall_s": round(time.perf_counter() - t0, 1),
    }
    print(json.dumps(entry, indent=2))
    if not args.no_save:
        save_entry(entry)


if __name__ == "__main__":
    main()
