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

import contextlib
import os
import socket
import time
from collections.abc import Callable, Iterator, Sequence

import numpy as np

from cmrt import inputs
from cmrt.errors import CmrtError, DiskFull, TransientFault, pending_termination
from cmrt.motion.curve import Cmrt
from cmrt.motion.task import Task
from cmrt.optimize.driver import (
    CmaState,
    best_cmrt,
    know_zero,
    new_state,
    restart_if_stalled,
    step,
    stop_reason,
)
from cmrt.optimize.parallel import Evaluator
from cmrt.optimize.settings import FAMILY_SIGMA0, STALE_AFTER_S, OptimizeSettings
from cmrt.service.known import start_point
from cmrt.service.progress import GenerationProgress, interactive
from cmrt.service.query import task_of
from cmrt.service.store import Claim, Generation, LostClaim, Run, RunProgress, RunSpec, Store, StoredEvaluation
from cmrt.service.warmstart import resolve_init
from cmrt.sim.objective import evaluate
from cmrt.sim.simulate import simulate
from cmrt.sim.validate import robustness

_DEFAULTS = OptimizeSettings()

__all__ = ["Claim", "LostClaim", "claim", "optimize_family", "optimize_now", "run_claimed", "submit", "work"]


def worker_id() -> str:
    """host:pid, the name a worker claims runs under."""
    return f"{socket.gethostname()}:{os.getpid()}"


def released(exc: KeyboardInterrupt, run_id: int) -> KeyboardInterrupt:
    """``exc`` (Ctrl-C or a terminating signal) marked with the run it gave back to the queue, so that the
    CLI can say which run is queued and how to resume it."""
    exc.released_run = run_id  # type: ignore[attr-defined]
    return exc


def given_back(fault: TransientFault, run_id: int, back: bool) -> TransientFault:
    """``fault`` (a full disk, a lost worker process) said with what became of the run: back in the queue, or
    (its give-back could not be written) left to be taken over once its heartbeat is stale."""
    where = (f"run {run_id} is back in the queue, its last checkpoint kept ('cmrt worker' resumes it)" if back else
             f"run {run_id} could not be given back: a worker takes it over once its heartbeat is stale")
    return type(fault)(f"{fault}; {where}")


def budget_min_evals(max_evals: int, min_evals: int | None) -> int:
    """The evaluations before which a stalled search may not stop: ``OptimizeSettings.min_evals`` (700, the
    paper's), or the budget if that is smaller; one given explicitly above the budget contradicts it (the run
    would end on its budget before it could ever stop as converged) and is refused."""
    if min_evals is None:
        return min(_DEFAULTS.min_evals, max_evals)
    if min_evals > max_evals:
        raise CmrtError(f"min-evals {min_evals} is more than the budget, max-evals {max_evals}: a stalled search "
                        f"could never stop before the budget ran out; give min-evals <= max-evals")
    return min_evals


def check_settings(*, seed: int, max_evals: int, popsize: int, sigma0: float | None, min_evals: int | None,
                   stall_generations: int) -> None:
    """The optimizer settings a run may be queued with (the CLI checks them before it opens the store)."""
    # the same ranges as the CLI's (cmrt.inputs): nothing non-finite or out of range reaches the store
    for value, where, allowed in ((seed, "seed", inputs.SEED), (max_evals, "max_evals", inputs.MAX_EVALS),
                                  (popsize, "popsize", inputs.POPSIZE), (sigma0, "sigma0", inputs.SIGMA0),
                                  (min_evals, "min_evals", inputs.MIN_EVALS),
                                  (stall_generations, "stall_generations", inputs.STALL_GENERATIONS)):
        if value is not None:
            allowed.check(value, where, text=False)
    if max_evals < popsize:  # a generation is popsize evaluations: the budget would be overrun, not kept
        raise CmrtError(f"a budget of {max_evals} evaluations (max-evals) is less than one generation of "
                        f"{popsize} (popsize): give at least {popsize}, or a smaller popsize")
    budget_min_evals(max_evals, min_evals)


def submit(
    store: Store,
    task: Task,
    *,
    seed: int = _DEFAULTS.seed,
    max_evals: int = _DEFAULTS.max_evals,
    popsize: int = _DEFAULTS.popsize,
    sigma0: float | None = None,
    min_evals: int | None = None,
    init: str | int | None = "auto",
    backend: str = "batch",
    stall_generations: int = _DEFAULTS.stall_generations,
) -> int:
    """Queue an optimization of ``task``; returns the run id. The optimizer's defaults are
    :class:`OptimizeSettings`'.

    ``init``: "auto" starts from the nearest known successful CMRT of the task (store, then
    library; cold if none), "none" from the zero CMRT, a run id from that run's best. ``sigma0``: None is
    ``OptimizeSettings.sigma0`` (0.5) from the zero CMRT and ``FAMILY_SIGMA0`` (0.15) from a known CMRT - a warm
    start searched with the cold step size loses its lead after its first candidate (measured on the bend at 0.5 s
    from 0.4 s's CMRT, to an objective of 0.40: cold 98-126 evaluations, warm with 0.5 80-121, with 0.15 5-15;
    docs/optimizer.md). ``min_evals``: None is
    :func:`budget_min_evals`' default (700, or the budget if smaller); more than ``max_evals`` is refused."""
    check_settings(seed=seed, max_evals=max_evals, popsize=popsize, sigma0=sigma0, min_evals=min_evals,
                   stall_generations=stall_generations)
    start = resolve_init(store, task, init)
    if sigma0 is None:
        sigma0 = _DEFAULTS.sigma0 if start.params is None else FAMILY_SIGMA0
    return store.add_run(RunSpec(
        task=task.name, speed=task.speed, params=task.params, task_hash=task.content_hash(),
        task_definition=task.to_dict(), seed=seed, max_evals=max_evals, popsize=popsize, sigma0=sigma0,
        min_evals=budget_min_evals(max_evals, min_evals), stop_threshold=task.stop_threshold,
        stall_generations=stall_generations,
        backend=backend, init_source=start.source, init_params=start.params,
        init_run=init if isinstance(init, int) and not isinstance(init, bool) else None,
        robust=task.robust.to_table() if task.robust.enabled else None, reference=task.reference_mode,
    ))


def claim(store: Store, worker: str, stale_after_s: float = STALE_AFTER_S, run_id: int | None = None,
          on_failure: Callable[[int, str], None] | None = None) -> Claim | None:
    """Take the oldest queued run, else an orphaned running one; None if there is none. A run whose row does not
    decode is failed with the reason (told to ``on_failure``) and the next one is taken."""
    return store.claim(worker, stale_after_s, run_id, on_failure)


def settings_for(run: Run, x0: tuple[float, ...] | None = None, n_params: int = 8) -> OptimizeSettings:
    """The optimizer settings a stored run was queued with; a row outside the ranges ``submit`` accepts (a
    store edited by someone else: a popsize of 20000) is refused with one line (the worker fails that run)."""
    for value, where, allowed in ((run.seed, "seed", inputs.SEED), (run.max_evals, "max_evals", inputs.MAX_EVALS),
                                  (run.popsize, "popsize", inputs.POPSIZE), (run.sigma0, "sigma0", inputs.SIGMA0),
                                  (run.min_evals, "min_evals", inputs.MIN_EVALS)):
        try:
            if value is not None:
                allowed.check(value, where, text=False)
        except CmrtError as exc:
            raise CmrtError(f"run {run.id} is outside what submit accepts: {exc}") from None
    if run.stall_generations is not None:
        inputs.STALL_GENERATIONS.check(run.stall_generations, "stall_generations", text=False)
    return OptimizeSettings(
        seed=run.seed, max_evals=run.max_evals, min_evals=run.min_evals, popsize=run.popsize,
        sigma0=run.sigma0, stop_threshold=run.stop_threshold or 0.0, x0=x0,
        stall_generations=run.stall_generations or _DEFAULTS.stall_generations, n_params=n_params,
    )


ProgressFn = Callable[[CmaState, list, float], None]


def run_claimed(
    store: Store,
    claim: Claim,
    evaluator: Evaluator,
    on_generation: ProgressFn | None = None,
    heartbeat_s: float = STALE_AFTER_S / 4,
) -> Run:
    """Optimize a claimed run to its end (or until the claim is lost: LostClaim). Returns the finished run.
    ``heartbeat_s``: how often the run's heartbeat is refreshed while a generation runs (a quarter of the
    workers' ``stale_after_s``, so a healthy worker is never taken for dead)."""
    with store.heartbeat(claim, heartbeat_s):
        return _run_claimed(store, claim, evaluator, on_generation)


def _run_claimed(store: Store, claim: Claim, evaluator: Evaluator, on_generation: ProgressFn | None) -> Run:
    run = store.run(claim.run_id)
    task = task_of(run)  # the definition must be the task the run names
    x0 = run.init_params
    if x0 is None and run.init_run is not None:  # queued by a cmrt before schema 3
        x0 = store.run(run.init_run).best_params
    if x0 is not None:  # a start copied from the store: checked like user input
        x0 = start_point(x0, task.clip_s, f"run {run.id}'s start point", task.n_cmrt_params)
    settings = settings_for(run, x0, task.n_cmrt_params)
    checkpoint = store.last_checkpoint(claim.run_id)
    state = CmaState.loads(checkpoint[1], settings, run_id=run.id) if checkpoint else new_state(settings)
    zero = None
    if not checkpoint:  # the zero CMRT is a candidate the search knows (a resumed run knows it already)
        zero = evaluator(task, [np.zeros(task.n_cmrt_params)])[0]
        know_zero(state, zero)

    if run.baseline_objective is None:
        if task.body != "planar":  # the 3D clip's score is the evaluator's (cmrt.sim.clip3d)
            base = zero if zero is not None else evaluator(task, [np.zeros(task.n_cmrt_params)])[0]
        else:
            base = evaluate(task, simulate(task, Cmrt.zero(task.clip_s), record=False))  # the score only
        store.record_baseline(claim, base.objective, base.fell, base.success)

    wall_before = run.wall_s or 0.0
    t_start = time.perf_counter()
    while (reason := stop_reason(state, settings)) is None:
        xs, records = step(state, lambda xs: evaluator(task, xs))
        restart_if_stalled(state, settings)
        wall = wall_before + time.perf_counter() - t_start
        gen = state.generation - 1
        progress = RunProgress(
            evaluations=state.evaluations, generations=state.generation, restarts=state.restarts,
            best_objective=state.best_objective, best_params=tuple(state.best_x.tolist()),
            best_fell=state.best_fell, best_success=state.best_success,
            best_cmrt=best_cmrt(state, task.clip_s).to_dict(), wall_s=wall,
            eval_s_added=sum(r.seconds for r in records),
        )
        generation = Generation(
            gen=gen, sigma=float(state.es.sigma), best_objective=state.best_objective,
            gen_best_objective=min(r.objective for r in records), mean=tuple(map(float, state.es.mean)),
            evaluations=state.evaluations, created_at=time.time(),
        )
        evaluations = [StoredEvaluation(gen=gen, idx=i, params=tuple(x.tolist()), objective=r.objective,
                                        fell=r.fell, success=r.success, seconds=r.seconds)
                       for i, (x, r) in enumerate(zip(xs, records, strict=True))]
        store.commit_generation(claim, progress, generation, evaluations, state.dumps())
        if on_generation:
            on_generation(state, records, wall)
    store.finish(claim, reason, robustness(task, best_cmrt(state, task.clip_s)))  # the validation ensemble
    return store.run(claim.run_id)


def optimize_now(
    store: Store,
    task: Task,
    evaluator: Evaluator | None = None,
    on_generation: ProgressFn | None = None,
    *,
    progress: bool | None = None,
    **submit_kwargs,
) -> Run:
    """Submit a run and optimize it in this process (``cmrt optimize``); returns the finished run.

    Args:
        evaluator: how candidates are simulated (default: the batched evaluator, closed afterwards).
        on_generation: called after every committed generation with (state, records, wall_s).
        progress: a progress bar on stderr (``cmrt.service.progress``) when no ``on_generation`` is given: None
            shows one in an interactive session (a Python prompt, IPython, Jupyter), True always, False never.
        submit_kwargs: as :func:`submit` (seed, max_evals, popsize, sigma0, min_evals, init, ...).
    """
    with _evaluator(evaluator) as ev:
        run_id = submit(store, task, backend=ev.backend, **submit_kwargs)
        c = claim(store, worker_id(), run_id=run_id)
        try:
            with _shown(store, run_id, on_generation, progress) as report:
                return run_claimed(store, c, ev, report)
        except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM: back in the queue, a worker resumes it
            store.release(c)
            raise released(exc, run_id) from None
        except TransientFault as exc:
            raise given_back(exc, run_id, store.retry_later(c, str(exc))) from exc
        except Exception as exc:  # never leave the run 'running' until its heartbeat goes stale
            if (terminated := pending_termination()) is not None:  # a signal inside an SQLite step
                store.release(c)
                raise released(terminated, run_id) from exc
            store.mark_failed(c, str(exc) if isinstance(exc, CmrtError) else f"{type(exc).__name__}: {exc}")
            raise


def optimize_family(
    store: Store,
    tasks: Sequence[Task],
    evaluator: Evaluator | None = None,
    *,
    family_sigma0: float = FAMILY_SIGMA0,
    on_generation: ProgressFn | None = None,
    on_run: Callable[[Run], None] | None = None,
    progress: bool | None = None,
    **submit_kwargs,
) -> list[Run]:
    """Optimize a family of tasks (e.g. one task at several speeds) in order, each member after the first
    warm-started from the previous member's best with step size ``family_sigma0``: the members stay near
    their neighbour, one family shape that interpolates well (ABC section 5).

    ``submit_kwargs`` apply to every member (its ``init`` and ``sigma0`` to the first only); ``progress`` as
    :func:`optimize_now`'s, a bar per member."""
    inputs.SIGMA0.check(family_sigma0, "family_sigma0", text=False)
    if isinstance(submit_kwargs.get("init"), int) and not isinstance(submit_kwargs.get("init"), bool):
        raise CmrtError("a family's members start from each other: give no run id as init")
    runs: list[Run] = []
    with _evaluator(evaluator) as ev:
        for task in tasks:
            kwargs = dict(submit_kwargs)
            if runs:
                kwargs.update(init=runs[-1].id, sigma0=family_sigma0)
            runs.append(optimize_now(store, task, ev, on_generation, progress=progress, **kwargs))
            if on_run:
                on_run(runs[-1])
    return runs


@contextlib.contextmanager
def _shown(store: Store, run_id: int, on_generation: ProgressFn | None, progress: bool | None
           ) -> Iterator[ProgressFn | None]:
    """The caller's ``on_generation``, or a progress bar of run ``run_id`` (``progress``: None shows one in an
    interactive session) closed when the run ends."""
    if on_generation is not None or not (progress or (progress is None and interactive())):
        yield on_generation
        return
    bar = GenerationProgress(store.run(run_id).max_evals, f"run {run_id}", bar=True)
    try:
        yield bar
    finally:
        bar.close()


@contextlib.contextmanager
def _evaluator(evaluator: Evaluator | None) -> Iterator[Evaluator]:
    """The caller's evaluator, or a batched one of our own that we close."""
    if evaluator is not None:
        yield evaluator
        return
    own = Evaluator("batch")
    try:
        yield own
    finally:
        own.close()


def work(
    store: Store,
    evaluator: Evaluator | None = None,
    *,
    until_idle: bool = False,
    once: bool = False,
    stale_after_s: float = STALE_AFTER_S,
    poll_s: float = 2.0,
    on_claim: Callable[[Claim], None] | None = None,
    on_generation: ProgressFn | None = None,
    on_failure: Callable[[int, str], None] | None = None,
    on_done: Callable[[Run], None] | None = None,
    on_idle: Callable[[], None] | None = None,
    progress: bool | None = None,
) -> list[int]:
    """The worker loop: claim, optimize, repeat. Returns the ids of the runs it finished.

    ``on_done(run)`` is called for each finished run; ``on_idle()`` once each time the queue is found empty
    and the worker starts waiting (not with ``until_idle`` or ``once``, which return then).

    A transient fault (full disk, lost worker process: :class:`TransientFault`) gives the run back to the
    queue - it resumes from its last checkpoint - a bounded number of times (``store.MAX_RETRIES``); any
    other error marks it failed with the message (``on_failure(run_id, message)``) and the worker goes on.
    Ctrl-C and SIGTERM give the current run back to the queue and stop the worker. ``evaluator`` defaults
    to the batched one, as in :func:`optimize_now`; ``progress`` as there (a bar per run).
    """
    inputs.STALE_AFTER_S.check(stale_after_s, "stale_after_s", text=False)
    me = worker_id()
    finished = []
    waiting = False
    with _evaluator(evaluator) as ev:
        while True:
            c = claim(store, me, stale_after_s, on_failure=on_failure)
            if c is None:
                if until_idle or once:
                    return finished
                if on_idle and not waiting:
                    on_idle()
                waiting = True
                time.sleep(poll_s)
                continue
            waiting = False
            if on_claim:
                on_claim(c)
            try:
                with _shown(store, c.run_id, on_generation, progress) as report:
                    run = run_claimed(store, c, ev, report, heartbeat_s=stale_after_s / 4)
                finished.append(c.run_id)
                if on_done:
                    on_done(run)
            except LostClaim:
                pass
            except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM (cmrt.errors.Terminated)
                store.release(c)
                raise released(exc, c.run_id) from None
            except TransientFault as exc:
                back = store.retry_later(c, str(exc))
                if isinstance(exc, DiskFull):  # the next run could not be written either: stop, exit 75
                    raise given_back(exc, c.run_id, back) from exc
                if on_failure:
                    on_failure(c.run_id, f"transient fault, back in the queue: {exc}")
            except Exception as exc:  # a bug or a bad stored run must not take the worker (and the queue) down
                if (terminated := pending_termination()) is not None:  # a signal inside an SQLite step
                    store.release(c)
                    raise released(terminated, c.run_id) from exc
                message = str(exc) if isinstance(exc, CmrtError) else f"{type(exc).__name__}: {exc}"
                store.mark_failed(c, message)
                if on_failure:
                    on_failure(c.run_id, message)
            if once:
                return finished
