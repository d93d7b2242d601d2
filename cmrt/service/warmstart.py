"""Where an optimization starts: cold (the zero CMRT) or from the nearest known CMRT of the task.

``--init auto`` (the default) looks for the CMRT of the same task whose parameters are
closest to the run's: successful finished runs in the store first, then the library.
Parameters are compared relative to the task's declared range (or to their own size
when no range is declared); a CMRT for another clip length is never used, since its
knots are placed on that clip. The chosen start point and where it came from are
stored with the run, so a resumed run never re-resolves it (the store may have changed).
"""

from __future__ import annotations

from dataclasses import dataclass

from cmrt.errors import CmrtError
from cmrt.motion.task import Task
from cmrt.service.known import CLIP_TOLERANCE_S, known_cmrts, start_point
from cmrt.service.store import Store

IGNORED_PARAMS = frozenset({"stop_threshold"})  # optimizer settings, not physics


@dataclass(frozen=True)
class Start:
    """A start point for CMA-ES: 8 CMRT parameters (12 in x and y) and where they came from."""

    params: tuple[float, ...] | None  # None: the zero CMRT (cold start)
    source: str  # "none", "run 12", "library (duration_s 0.4)"
    distance: float = 0.0  # how far the source's task parameters are from the run's (0: the same task)


COLD = Start(None, "none")


def task_distance(task: Task, other_params: dict[str, float]) -> float:
    """Sum over parameters of |difference| / scale: the task's range width, else the value's own size."""
    total = 0.0
    for key, value in task.params.items():
        if key in IGNORED_PARAMS:
            continue
        other = other_params.get(key, value)
        lo_hi = task.param_ranges.get(key)
        scale = (lo_hi[1] - lo_hi[0]) if lo_hi and lo_hi[1] > lo_hi[0] else max(abs(value), abs(other), 1e-9)
        total += abs(other - value) / scale
    return total


def _candidates(store: Store | None, task: Task) -> list[tuple[float, int, bool, float, Start]]:
    """(distance, other kind (robust vs plain) than the run, 0 store / 1 library, objective, start)."""
    found = []
    for known in known_cmrts(task, store):
        if len(known.cma_params) > task.n_cmrt_params:  # a CMRT in two axes does not start a one-axis search
            continue
        d = task_distance(task, known.params)
        if known.source == "library":
            label = f"library{' robust' if known.robust else ''}"
            label += f" ({task.speed_param} {known.speed:g})" if task.speed_param else ""
        else:
            label = known.source
        found.append((d, known.robust != task.robust.enabled, int(known.source == "library"), known.objective,
                      Start(known.cma_params, label, d)))
    return found


def nearest_start(store: Store | None, task: Task) -> Start | None:
    """The nearest known successful CMRT of this task; at equal distance one of the run's own kind (robust
    or plain) first, then the store before the library, then the lower objective. None if there is none."""
    found = _candidates(store, task)
    if not found:
        return None
    return min(found, key=lambda c: c[:4])[4]


def resolve_init(store: Store | None, task: Task, init: str | int | None) -> Start:
    """``init``: "auto" (nearest known CMRT, else cold), "none" (cold) or a run id."""
    if init is None or init == "none":
        return COLD
    if init == "auto":
        return nearest_start(store, task) or COLD
    if isinstance(init, bool) or not isinstance(init, int):
        raise CmrtError(f"--init must be auto, none or a run id, got '{init}'")
    if store is None:
        raise CmrtError("a run id as start needs a store")
    src = store.run(init)
    if src.best_params is None:
        raise CmrtError(f"run {init} has no result to start from")
    if abs(src.params["clip_s"] - task.clip_s) > CLIP_TOLERANCE_S:
        raise CmrtError(f"run {init} is for a {src.params['clip_s']:g} s clip, not {task.clip_s:g} s")
    params = start_point(src.best_params, task.clip_s, f"run {init}'s best CMRT", task.n_cmrt_params)  # checked
    return Start(params, f"run {init}", task_distance(task, src.params))
