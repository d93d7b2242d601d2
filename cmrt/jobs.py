"""The job queue on the store: submit, claim, run with checkpoints, resume orphans.

A run is a job. ``submit`` queues it with the full task definition (so later edits to a
task file do not change a queued run). A worker ``claim``s the oldest queued run
- or a ``running`` one whose heartbeat is older than ``stale_after_s`` (its worker
died) - in one ``BEGIN IMMEDIATE`` transaction, bumping the run's ``attempt``. Every
write the worker makes afterwards is fenced on (worker, attempt): if its claim was
taken over, it stops instead of writing twice.

Each generation commits its evaluations, the optimizer checkpoint and the run's
progress atomically; a resumed run reloads the last checkpoint and continues exactly
where the uninterrupted run would be.
"""

from __future__ import annotations

import json
import os
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass

from cmrt.curve import Cmrt
from cmrt.errors import CmrtError
from cmrt.objective import evaluate
from cmrt.optimize import CmaState, OptimizeSettings, best_cmrt, new_state, restart_if_stalled, step, stop_reason
from cmrt.parallel import Evaluator
from cmrt.simulate import simulate
from cmrt.store import Store
from cmrt.task import Task, task_from_dict
from cmrt.validate import robustness
from cmrt.warmstart import resolve_init

DEFAULT_STALE_AFTER_S = 120.0


class LostClaim(RuntimeError):
    """Another worker took this run over (ours was considered dead)."""


@dataclass(frozen=True)
class Claim:
    run_id: int
    worker: str
    attempt: int


def worker_id() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def submit(
    store: Store,
    task: Task,
    *,
    seed: int = 1,
    max_evals: int = 3000,
    popsize: int = 10,
    sigma0: float = 0.5,
    min_evals: int = 700,
    init: str | int | None = "auto",
    backend: str = "batch",
    stall_generations: int = OptimizeSettings.stall_generations,
) -> int:
    """Queue an optimization of ``task``; returns the run id.

    ``init``: "auto" starts from the nearest known successful CMRT of the task (store, then
    library; cold if none), "none" from the zero CMRT, a run id from that run's best."""
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise CmrtError("seed must be an integer")
    if max_evals < 1 or popsize < 2 or sigma0 <= 0 or min_evals < 0 or stall_generations < 1:
        raise CmrtError("need max_evals >= 1, popsize >= 2, sigma0 > 0, min_evals >= 0, stall_generations >= 1")
    start = resolve_init(store, task, init)
    row = {
        "task": task.name, "speed": task.speed, "params": json.dumps(task.params, sort_keys=True),
        "task_hash": task.content_hash(), "task_source": json.dumps(task.to_dict(), sort_keys=True),
        "seed": seed, "max_evals": max_evals, "popsize": popsize, "sigma0": sigma0, "min_evals": min_evals,
        "stop_threshold": task.stop_threshold, "backend": backend,
        "init_run": init if isinstance(init, int) and not isinstance(init, bool) else None,
        "robust": json.dumps(task.robust.to_table()) if task.robust.enabled else None,
        "init_source": start.source, "init_params": None if start.params is None else json.dumps(list(start.params)),
        "restarts": 0, "stall_generations": stall_generations,
        "status": "queued", "created_at": time.time(),
    }
    with store.transaction() as conn:
        cur = conn.execute(
            f"INSERT INTO runs ({', '.join(row)}) VALUES ({', '.join('?' * len(row))})", tuple(row.values())
        )
        return int(cur.lastrowid)


def claim(store: Store, worker: str, stale_after_s: float = DEFAULT_STALE_AFTER_S, run_id: int | None = None):
    """Take the oldest queued run, else an orphaned running one; None if there is none."""
    now = time.time()
    with store.transaction() as conn:
        if run_id is not None:
            row = conn.execute(
                "SELECT id FROM runs WHERE id = ? AND (status = 'queued' OR (status = 'running' AND heartbeat_at < ?))",
                (run_id, now - stale_after_s),
            ).fetchone()
        else:
            row = conn.execute("SELECT id FROM runs WHERE status = 'queued' ORDER BY id LIMIT 1").fetchone()
            if row is None:
                row = conn.execute(
                    "SELECT id FROM runs WHERE status = 'running' AND heartbeat_at < ? ORDER BY id LIMIT 1",
                    (now - stale_after_s,),
                ).fetchone()
        if row is None:
            return None
        rid = int(row[0])
        conn.execute(
            "UPDATE runs SET status = 'running', worker = ?, attempt = attempt + 1, heartbeat_at = ?, "
            "started_at = COALESCE(started_at, ?) WHERE id = ?",
            (worker, now, now, rid),
        )
        attempt = conn.execute("SELECT attempt FROM runs WHERE id = ?", (rid,)).fetchone()[0]
    return Claim(rid, worker, int(attempt))


def _fenced_update(conn, claim: Claim, sets: str, args: tuple) -> None:
    cur = conn.execute(
        f"UPDATE runs SET {sets} WHERE id = ? AND worker = ? AND attempt = ? AND status = 'running'",
        (*args, claim.run_id, claim.worker, claim.attempt),
    )
    if cur.rowcount != 1:
        raise LostClaim(f"run {claim.run_id} was taken over by another worker")


def settings_for(run: dict, x0: tuple[float, ...] | None = None) -> OptimizeSettings:
    return OptimizeSettings(
        seed=run["seed"], max_evals=run["max_evals"], min_evals=run["min_evals"], popsize=run["popsize"],
        sigma0=run["sigma0"], stop_threshold=run["stop_threshold"] or 0.0, x0=x0,
        stall_generations=run.get("stall_generations") or OptimizeSettings.stall_generations,
    )


def task_of(run: dict) -> Task:
    return task_from_dict(json.loads(run["task_source"]), source=f"run {run['id']}")


ProgressFn = Callable[[CmaState, list, float], None]


def run_claimed(
    store: Store,
    claim: Claim,
    evaluator: Evaluator,
    on_generation: ProgressFn | None = None,
) -> dict:
    """Optimize a claimed run to its end (or until the claim is lost). Returns the run row."""
    run = store.run(claim.run_id)
    task = task_of(run)
    x0 = tuple(run["init_params"]) if run.get("init_params") else None
    if x0 is None and run["init_run"] is not None:  # queued by a cmrt before schema 3
        x0 = tuple(store.run(run["init_run"])["best_params"])
    settings = settings_for(run, x0)
    checkpoint = store.last_checkpoint(claim.run_id)
    state = CmaState.loads(checkpoint[1]) if checkpoint else new_state(settings)

    if run["baseline_objective"] is None:
        base = evaluate(task, simulate(task, Cmrt.zero(task.clip_s)))
        with store.transaction() as conn:
            _fenced_update(conn, claim, "baseline_objective = ?, baseline_fell = ?, baseline_success = ?, "
                           "heartbeat_at = ?", (base.objective, int(base.fell), int(base.success), time.time()))

    wall_before = run["wall_s"] or 0.0
    t_start = time.perf_counter()
    while (reason := stop_reason(state, settings)) is None:
        xs, records = step(state, lambda xs: evaluator(task, xs))
        restart_if_stalled(state, settings)
        now = time.time()
        wall = wall_before + time.perf_counter() - t_start
        gen = state.generation - 1
        with store.transaction() as conn:
            _fenced_update(
                conn, claim,
                "heartbeat_at = ?, evaluations = ?, generations = ?, best_objective = ?, best_params = ?, "
                "best_fell = ?, best_success = ?, best_cmrt = ?, wall_s = ?, eval_s = COALESCE(eval_s, 0) + ?, "
                "restarts = ?",
                (now, state.evaluations, state.generation, state.best_objective,
                 json.dumps(state.best_x.tolist()), int(state.best_fell), int(state.best_success),
                 best_cmrt(state, task.clip_s).to_json(), wall, sum(r.seconds for r in records), state.restarts),
            )
            conn.executemany(
                "INSERT INTO evaluations (run_id, gen, idx, params, objective, fell, success, seconds) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                [(claim.run_id, gen, i, json.dumps(x.tolist()), r.objective, int(r.fell), int(r.success), r.seconds)
                 for i, (x, r) in enumerate(zip(xs, records, strict=True))],
            )
            conn.execute(
                "INSERT INTO generations (run_id, gen, sigma, best_objective, gen_best_objective, mean, "
                "evaluations, checkpoint, created_at) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (claim.run_id, gen, float(state.es.sigma), state.best_objective,
                 min(r.objective for r in records), json.dumps(list(map(float, state.es.mean))),
                 state.evaluations, state.dumps(), now),
            )
        if on_generation:
            on_generation(state, records, wall)
    figures = robustness(task, best_cmrt(state, task.clip_s))  # the validation ensemble (cmrt.validate)
    with store.transaction() as conn:
        _fenced_update(conn, claim, "status = 'done', stop_reason = ?, finished_at = ?, heartbeat_at = ?, "
                       "robustness = ?", (reason, time.time(), time.time(), json.dumps(figures)))
    return store.run(claim.run_id)


def optimize_now(
    store: Store,
    task: Task,
    evaluator: Evaluator | None = None,
    on_generation: ProgressFn | None = None,
    **submit_kwargs,
) -> dict:
    """Submit a run and optimize it in this process (``cmrt optimize``); returns the finished run."""
    own = evaluator is None
    evaluator = evaluator or Evaluator("batch")
    try:
        run_id = submit(store, task, backend=evaluator.backend, **submit_kwargs)
        c = claim(store, worker_id(), run_id=run_id)
        try:
            return run_claimed(store, c, evaluator, on_generation)
        except KeyboardInterrupt:
            release(store, c)
            raise
    finally:
        if own:
            evaluator.close()


def release(store: Store, claim: Claim) -> None:
    """Give a run back to the queue (worker stopped by the user); it resumes from its checkpoint."""
    try:
        with store.transaction() as conn:
            _fenced_update(conn, claim, "status = 'queued', worker = NULL", ())
    except LostClaim:
        pass


def mark_failed(store: Store, claim: Claim, message: str) -> None:
    try:
        with store.transaction() as conn:
            _fenced_update(conn, claim, "status = 'failed', error = ?, finished_at = ?", (message, time.time()))
    except LostClaim:
        pass


def work(
    store: Store,
    evaluator: Evaluator,
    *,
    until_idle: bool = False,
    once: bool = False,
    stale_after_s: float = DEFAULT_STALE_AFTER_S,
    poll_s: float = 2.0,
    on_claim: Callable[[Claim], None] | None = None,
    on_generation: ProgressFn | None = None,
) -> list[int]:
    """The worker loop; returns the ids of the runs it finished."""
    me = worker_id()
    finished = []
    while True:
        c = claim(store, me, stale_after_s)
        if c is None:
            if until_idle or once:
                return finished
            time.sleep(poll_s)
            continue
        if on_claim:
            on_claim(c)
        try:
            run_claimed(store, c, evaluator, on_generation)
            finished.append(c.run_id)
        except LostClaim:
            pass
        except KeyboardInterrupt:
            release(store, c)
            raise
        except CmrtError as exc:
            mark_failed(store, c, str(exc))
        except Exception as exc:  # a bug must not take the worker (and the queue) down
            mark_failed(store, c, f"{type(exc).__name__}: {exc}")
        if once:
            return finished
