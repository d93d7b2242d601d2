"""Checkpoint blob size and write/read time: cmrt's data-only format vs the pickle it replaced.

The state is a typical run's after ``--generations`` generations of ``--popsize`` candidates
(a toy objective: the optimizer's state does not depend on what is simulated), plus one
after IPOP restarts (larger population, larger archives). Times are the best of ``--repeat``.
Reading includes the checks of ``CmaState.loads`` (options rebuilt and compared).

    python tools/bench_checkpoint.py [--popsize 10] [--generations 20] [--repeat 50] [--json]
"""

from __future__ import annotations

import argparse
import json
import pickle
import time

import numpy as np

from cmrt import OptimizeSettings
from cmrt.optimize.driver import CmaState, new_state, restart_if_stalled, step
from cmrt.sim.objective import EvalRecord


def _sphere(xs):
    return [EvalRecord(float(np.sum((x - 0.3) ** 2)), False, 0.0, success=True) for x in xs]


def _flat(xs):
    return [EvalRecord(1.0, True, 0.0) for _ in xs]


def _best_time(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def measure(label: str, state: CmaState, settings: OptimizeSettings, repeat: int) -> dict:
    blob, pick = state.dumps(), pickle.dumps(state, protocol=pickle.HIGHEST_PROTOCOL)
    CmaState.loads(blob, settings)  # warm the options cache: a worker pays it once per population
    return {
        "state": label, "popsize": int(state.es.popsize), "generations": state.generation,
        "restarts": state.restarts,
        "cmrt_bytes": len(blob), "pickle_bytes": len(pick),
        "cmrt_dumps_ms": 1e3 * _best_time(state.dumps, repeat),
        "pickle_dumps_ms": 1e3 * _best_time(lambda: pickle.dumps(state, protocol=pickle.HIGHEST_PROTOCOL), repeat),
        "cmrt_loads_ms": 1e3 * _best_time(lambda: CmaState.loads(blob, settings), repeat),
        "pickle_loads_ms": 1e3 * _best_time(lambda: pickle.loads(pick), repeat),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description="checkpoint size and speed vs pickle")
    ap.add_argument("--popsize", type=int, default=10)
    ap.add_argument("--generations", type=int, default=20)
    ap.add_argument("--repeat", type=int, default=50)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()

    typical = OptimizeSettings(seed=1, popsize=args.popsize)
    state = new_state(typical)
    for _ in range(args.generations):
        step(state, _sphere)
    rows = [measure("typical", state, typical, args.repeat)]

    stalling = OptimizeSettings(seed=1, popsize=args.popsize, stall_generations=5, min_evals=10_000, max_evals=10_000)
    state = new_state(stalling)
    while state.restarts < 3:
        step(state, _flat)
        restart_if_stalled(state, stalling)
    for _ in range(args.generations):
        step(state, _flat)
    rows.append(measure("after 3 restarts", state, stalling, args.repeat))

    if args.json:
        print(json.dumps(rows, indent=2))
        return
    print(f"{'state':18s} {'pop':>4s} {'gens':>5s} {'cmrt B':>8s} {'pickle B':>9s} {'dumps ms':>15s} "
          f"{'loads ms':>15s}   (cmrt / pickle)")
    for r in rows:
        print(f"{r['state']:18s} {r['popsize']:4d} {r['generations']:5d} {r['cmrt_bytes']:8d} {r['pickle_bytes']:9d} "
              f"{r['cmrt_dumps_ms']:7.2f} /{r['pickle_dumps_ms']:6.2f} "
              f"{r['cmrt_loads_ms']:7.2f} /{r['pickle_loads_ms']:6.2f}")


if __name__ == "__main__":
    main()
