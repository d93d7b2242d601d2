"""The CMRTs known for a task: successful stored runs and the shipped library, read through one filter.

Warm starts (``service.warmstart``) and interpolation (``service.interpolate``) both ask "which CMRTs do we
have for this task?"; they ask it here, so that a CMRT counts as the same task's by one rule: the same task
name and the same controller reference mode (a CMRT belongs to its mode), optionally of one kind (plain or
robust), only successes, only for the same clip length (a CMRT's knots are placed on its clip).
"""

from __future__ import annotations

import numpy as np

from cmrt.motion.curve import Cmrt
from cmrt.motion.library import KnownCmrt, library_cmrts
from cmrt.motion.task import Task
from cmrt.service.store import Run, Store

CLIP_TOLERANCE_S = 1e-9
SOURCES = ("store", "library")


def run_cmrt(run: Run) -> KnownCmrt:
    """A finished run's best CMRT as a record (its optimizer parameters as stored, bit for bit; the curve as
    stored, else made from them)."""
    curve = (Cmrt.from_dict(run.best_cmrt, f"run {run.id}'s best CMRT") if run.best_cmrt is not None
             else Cmrt.from_params(np.asarray(run.best_params, dtype=float), run.params["clip_s"]))
    return KnownCmrt(task=run.task, params=run.params, reference=run.reference, robust=run.robust is not None,
                     curve=curve, cma_params=tuple(run.best_params),
                     objective=run.best_objective, success=bool(run.best_success), source=f"run {run.id}",
                     speed=run.speed)


def known_cmrts(task: Task, store: Store | None = None, sources: tuple[str, ...] = SOURCES,
                robust: bool | None = None, same_clip: bool = True) -> list[KnownCmrt]:
    """The successful CMRTs of ``task``'s name and reference mode: the store's finished runs (oldest first),
    then the library's entries (in file order). ``robust``: only that kind (None: both); ``same_clip``: only
    those for the task's clip length."""
    found: list[KnownCmrt] = []
    if "store" in sources and store is not None:
        found += [run_cmrt(run) for run in store.successful_runs(task.name, task.reference_mode)]
    if "library" in sources:
        found += [e for e in library_cmrts() if e.task == task.name and e.reference == task.reference_mode
                  and e.success]
    return [k for k in found if (robust is None or k.robust == robust)
            and (not same_clip or abs(k.clip_s - task.clip_s) <= CLIP_TOLERANCE_S)]
