"""Reproduce ABC Table 1 with outcome columns: zero CMRT vs optimized vs library, per task.

For each row: the zero-CMRT clip, a fresh CMA-ES run (seed 1, the task's stop threshold,
default batched backend) into a scratch store, and the CMRT shipped in the library;
objective and outcome (success, fell, motion not performed / goal missed), evaluations and
wall time, next to the paper's timings, threshold, iterations N and computation time C (s).

    python tools/reproduce_table1.py [--rows fast-bend,catch] [--max-evals N] [--json]

``--max-evals`` caps each run's budget (default: the optimizer's own), for a quick check that the table runs.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from cmrt import Evaluator, evaluate, library_curve, load_task, open_store, optimize_now, simulate

# name: (task, overrides, paper row (L, P, T, D, delta, N, C) or None)
ROWS = {
    "push": ("push", {}, (3.0, 1, 0.35, 1.65, 0.6, 149, 328)),
    "catch": ("catch", {}, (3.0, 1, 0.3, 1.7, 0.9, 18, 40)),
    # the zero CMRT already succeeds on the slow bend (objective 0.20): a threshold below it
    "slow-bend": ("bend", {"duration_s": 1.2, "stop_threshold": 0.1}, (2.6, 1, 1.2, 0.4, 0.9, 328, 641)),
    "fast-bend": ("bend", {"duration_s": 0.4}, (2.6, 1, 0.4, 1.2, 1.1, 683, 1366)),
    "punch": ("punch", {}, None),
    "rise": ("rise", {"duration_s": 0.4}, None),
}


def outcome(ev) -> str:
    """A clip's verdict in a few words: success, the fall, or the rules it broke (``Evaluation.failed_rules``)."""
    if ev.success:
        return "success"
    if ev.fell:
        return f"fell {ev.fall_time_s:.2f} s"
    words = {"performed": "goal missed" if ev.task_success is False else "not performed", "on_time": "late",
             "settled": "not settled", "plan": "plan not carried out"}
    return ", ".join(words.get(rule, rule.replace("_", " ")) for rule in ev.failed_rules)


def row(name: str, store_dir: Path, max_evals: int | None = None) -> dict:
    task_name, overrides, paper = ROWS[name]
    task = load_task(task_name).with_params(**overrides)
    zero = evaluate(task, simulate(task, record=False))
    lib = evaluate(task, simulate(task, library_curve(task), record=False))
    t0 = time.perf_counter()
    with open_store(store_dir / f"{name}.sqlite") as store, Evaluator("batch") as ev:
        budget = {} if max_evals is None else {"max_evals": max_evals}
        run = optimize_now(store, task, ev, seed=1, init="none", **budget)
    wall = time.perf_counter() - t0
    out = {
        "row": name, "task": task.name, "L": task.clip_s, "P": task.preparation_s, "T": task.duration_s,
        "D": round(task.decay_s, 6), "threshold": task.stop_threshold,
        "zero_objective": zero.objective, "zero_outcome": outcome(zero), "zero_success": zero.success,
        "optimized_objective": run.best_objective, "optimized_success": run.best_success,
        "evaluations": run.evaluations, "stop_reason": run.stop_reason, "wall_s": round(wall, 1),
        "library_objective": lib.objective, "library_outcome": outcome(lib), "library_success": lib.success,
        "library_final_pose_error_rad": lib.final_pose_error_rad,
    }
    if paper:
        out.update(dict(zip(("paper_L", "paper_P", "paper_T", "paper_D", "paper_delta", "paper_N", "paper_C_s"),
                            paper, strict=True)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description="ABC Table 1 with outcomes")
    ap.add_argument("--rows", default=",".join(ROWS))
    ap.add_argument("--max-evals", type=int, help="budget of each run (default: the optimizer's)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        rows = [row(r, Path(tmp), args.max_evals) for r in args.rows.split(",")]
    if args.json:
        print(json.dumps(rows, indent=2))
        return
    print("| motion | L | P | T | D | threshold (paper) | zero CMRT: objective, outcome | optimized: objective, "
          "success, evals, wall s (paper N / C s) | library: objective, outcome |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        paper = (f" ({r['paper_N']} / {r['paper_C_s']})" if "paper_N" in r else "")
        delta = f"{r['threshold']:g} ({r['paper_delta']:g})" if "paper_delta" in r else f"{r['threshold']:g}"
        print(f"| {r['row']} | {r['L']:g} | {r['P']:g} | {r['T']:g} | {r['D']:g} | {delta} | "
              f"{r['zero_objective']:.2f}, {r['zero_outcome']} | "
              f"{r['optimized_objective']:.3f}, {'yes' if r['optimized_success'] else 'no'}, {r['evaluations']}, "
              f"{r['wall_s']:.1f}{paper} | {r['library_objective']:.3f}, {r['library_outcome']} |")


if __name__ == "__main__":
    main()
