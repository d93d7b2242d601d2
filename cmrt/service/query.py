"""Read-side of the store: runs, the best run for a task, curves, exports (all through ``Store``)."""

from __future__ import annotations

import csv
import io
from dataclasses import asdict
from typing import TYPE_CHECKING

from cmrt import inputs
from cmrt.errors import CmrtError
from cmrt.inputs import shown
from cmrt.optimize.settings import OptimizeSettings
from cmrt.service.store import Run, Store

if TYPE_CHECKING:
    from cmrt.motion.curve import Cmrt
    from cmrt.motion.task import Task

SUMMARY_KEYS = ("id", "task", "speed", "reference", "status", "seed", "best_objective", "best_success", "best_fell",
                "baseline_objective", "baseline_success", "baseline_fell", "evaluations", "generations", "stop_reason",
                "wall_s")


def run_summary(run: Run) -> dict:
    """The columns ``cmrt runs`` lists."""
    return {k: getattr(run, k) for k in SUMMARY_KEYS}


def search_start(run: Run) -> str:
    """Where a run's search started, in words (its ``init_source``)."""
    source = run.init_source or "none"
    if source == "none":
        return f"started cold from the zero CMRT (sigma {run.sigma0:g})"
    if source.startswith("library"):
        kind, _, where = source.partition(" (")
        return f"started from the {kind} CMRT" + (f" ({where}" if where else "") + f", sigma {run.sigma0:g}"
    return f"started from {source}'s best CMRT, sigma {run.sigma0:g}"


def search_summary(run: Run) -> str:
    """Where a run's search started and why it stopped, in one sentence - the line a worker, ``optimize``,
    ``best``, ``show`` and the dashboard print - with the flag that asks for a search when a warm start ended it
    at once."""
    start, n = search_start(run), run.evaluations
    if run.status in ("queued", "running"):
        return f"{start}; {run.status}, {n} evaluations so far"
    if run.status == "failed":
        return f"{start}; failed after {n} evaluations: {run.error}"
    why = run.stop_reason or ""
    threshold = "-" if run.stop_threshold is None else f"{run.stop_threshold:g}"
    if why == "threshold" and run.generations <= 1 and (run.init_source or "none") != "none":
        return (f"{start}; it already met the stop threshold {threshold}: {n} evaluations (a search of its own: "
                f"--init none; below the threshold: --set stop_threshold=0)")
    if why == "threshold":
        return f"{start}; stopped at the stop threshold {threshold} after {n} evaluations"
    if why == "budget":
        return f"{start}; its budget ran out: {n} of {run.max_evals} evaluations"
    if why.startswith("converged"):
        stall = run.stall_generations or OptimizeSettings.stall_generations
        return (f"{start}; it stopped improving over {stall} generations with no restart left that fits: "
                f"{n} evaluations, {run.restarts or 0} restarts")
    return f"{start}; stopped ({why}) after {n} evaluations"


def run_details(store: Store, run_id: int) -> dict:
    """Everything ``cmrt show`` prints: the run decoded, with its throughput and :func:`search_summary`."""
    run = store.run(run_id)
    out = run.to_dict()
    out["search"] = search_summary(run)
    eval_s = run.eval_s or 0.0
    out["evaluations_per_s"] = run.evaluations / run.wall_s if run.wall_s else None
    out["mean_eval_s"] = eval_s / run.evaluations if run.evaluations else None
    return out


def best_run(store: Store, task: Task) -> Run:
    """The best finished run for exactly this task (same physics hash): successes first, then the
    lowest objective - of every run of the task in the store, not necessarily one you just submitted
    (``store.run(run_id)`` reads that one). CmrtError if the task has no finished run."""
    run = store.best_run(task.content_hash())
    if run is None:
        speed = f" at speed {task.speed:g}" if task.speed is not None else ""
        raise CmrtError(f"no finished run for task '{task.name}'{speed} with these parameters in {store.path}")
    return run


def task_of(run: Run) -> Task:
    """The task exactly as the run was queued with (not the task file as it is now), checked like a task file
    and against the run: a definition that is not the task named by the run's name and physics hash (``{}``,
    another task's) is refused, so a worker never optimizes something else than the run says."""
    from cmrt.motion.taskfile import task_from_dict  # MuJoCo: listing and showing runs do not load it

    task = task_from_dict(run.task_definition, source=f"run {run.id}")
    if task.name != run.task or task.content_hash() != run.task_hash:
        raise CmrtError(f"the store is damaged: run {run.id}: its task definition is not the task {shown(run.task)} "
                        "it was queued as (another name or physics hash)")
    return task


def stored_curve(run: Run) -> Cmrt:
    """A run's best CMRT, held to what a CMRT file may hold (knots inside the clip, displacements within
    ``cmrt.motion.curve.VALUE_M``); CmrtError if it has none yet."""
    if not run.best_cmrt:
        raise CmrtError(f"run {run.id} has no result yet (status {run.status})")
    from cmrt.motion.curve import VALUE_M, Cmrt  # scipy: listing and showing runs do not load it

    return Cmrt.from_dict(run.best_cmrt, f"run {run.id}'s best CMRT", VALUE_M)


def run_curve(store: Store, run_id: int) -> Cmrt:
    """The best CMRT a stored run found so far."""
    return stored_curve(store.run(run_id))


def export_run(store: Store, run_id: int, fmt: str) -> str:
    """json: run, generations and evaluations (non-finite numbers as null: valid JSON); csv: one row per
    evaluation, its CMRT as knots (times in s, CoM displacements in m) and then CMA-ES's raw 8-vector (a CMRT in x
    and y: its values across too, and 12 numbers)."""
    if fmt not in ("json", "csv"):
        raise CmrtError(f"--format must be json or csv, got '{fmt}'")
    with store.snapshot():  # one consistent state even while a worker commits generations
        details, generations, evaluations = run_details(store, run_id), store.generations(run_id), \
            store.evaluations(run_id)
    if fmt == "json":
        return inputs.dumps(
            {"run": details, "generations": [asdict(g) for g in generations],
             "evaluations": [asdict(e) for e in evaluations]},
            indent=2,
        )
    from cmrt.motion.curve import N_KNOTS, Cmrt  # scipy: only the CSV export loads it

    clip_s = float(details["params"]["clip_s"])
    buf = io.StringIO()
    w = csv.writer(buf)
    knots = range(1, N_KNOTS + 1)
    two_axes = any(len(e.params) > 2 * N_KNOTS for e in evaluations)  # a run's CMRTs all have one dimension
    cross = [f"knot{i}_cross_displacement_m" for i in knots] if two_axes else []  # a CMRT in x and y's
    w.writerow(["run_id", "gen", "idx", "objective", "fell", "success", "seconds"]
               + [f"knot{i}_time_s" for i in knots] + [f"knot{i}_displacement_m" for i in knots] + cross
               + [f"p{i}" for i in range((3 if two_axes else 2) * N_KNOTS)])
    for e in evaluations:
        success = "" if e.success is None else int(e.success)
        curve = Cmrt.from_params(e.params, clip_s)  # the knots a person plots; the raw CMA-ES vector after them
        row = [run_id, e.gen, e.idx, repr(e.objective), int(e.fell), success, e.seconds]
        across = [repr(v) for v in curve.cross.values_m] if two_axes else []
        w.writerow(row + [repr(t) for t in curve.knot_times_s] + [repr(v) for v in curve.values_m] + across
                   + [repr(p) for p in e.params])
    return buf.getvalue()
