"""Read-side of the store: runs, the best run for a task, curves, exports."""

from __future__ import annotations

import csv
import io
import json

from cmrt.curve import Cmrt
from cmrt.errors import CmrtError
from cmrt.store import Store
from cmrt.task import Task

SUMMARY_KEYS = ("id", "task", "speed", "status", "seed", "best_objective", "best_success", "best_fell",
                "baseline_objective", "baseline_success", "baseline_fell", "evaluations", "generations", "stop_reason",
                "wall_s")


def run_summary(run: dict) -> dict:
    return {k: run.get(k) for k in SUMMARY_KEYS}


def run_details(store: Store, run_id: int) -> dict:
    """Everything ``cmrt show`` prints: the run row without internal blobs, decoded."""
    run = store.run(run_id)
    out = {k: v for k, v in run.items() if k != "task_source"}
    out["task_definition"] = json.loads(run["task_source"])
    eval_s = run.get("eval_s") or 0.0
    out["evaluations_per_s"] = run["evaluations"] / run["wall_s"] if run.get("wall_s") else None
    out["mean_eval_s"] = eval_s / run["evaluations"] if run["evaluations"] else None
    return out


def best_run(store: Store, task: Task) -> dict:
    """The best finished run for exactly this task (same physics hash): successes first, then the
    lowest objective."""
    row = store.conn.execute(
        "SELECT id FROM runs WHERE status = 'done' AND task_hash = ? AND best_objective IS NOT NULL "
        "ORDER BY COALESCE(best_success, 0) DESC, best_fell ASC, best_objective ASC, id ASC LIMIT 1",
        (task.content_hash(),),
    ).fetchone()
    if row is None:
        speed = f" at speed {task.speed:g}" if task.speed is not None else ""
        raise CmrtError(f"no finished run for task '{task.name}'{speed} with these parameters in {store.path}")
    return store.run(int(row[0]))


def run_curve(store: Store, run_id: int) -> Cmrt:
    run = store.run(run_id)
    if not run.get("best_cmrt"):
        raise CmrtError(f"run {run_id} has no result yet (status {run['status']})")
    return Cmrt.from_dict(run["best_cmrt"])


def export_run(store: Store, run_id: int, fmt: str) -> str:
    """json: run, generations and evaluations; csv: one row per evaluation."""
    if fmt not in ("json", "csv"):
        raise CmrtError(f"--format must be json or csv, got '{fmt}'")
    evaluations = store.evaluations(run_id)
    if fmt == "json":
        return json.dumps(
            {"run": run_details(store, run_id), "generations": store.generations(run_id), "evaluations": evaluations},
            indent=2,
        )
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["run_id", "gen", "idx", "objective", "fell", "success", "seconds"] + [f"p{i}" for i in range(8)])
    for e in evaluations:
        success = "" if e["success"] is None else int(e["success"])
        row = [run_id, e["gen"], e["idx"], repr(e["objective"]), int(e["fell"]), success, e["seconds"]]
        w.writerow(row + [repr(p) for p in e["params"]])
    return buf.getvalue()
