"""The CMRTs known for a task: successful stored runs and the shipped library, read through one filter.

Warm starts (``service.warmstart``) and interpolation (``service.interpolate``) both ask "which CMRTs do we
have for this task?"; they ask it here, so that a CMRT counts as the same task's by one rule: the same task
name, the same motion (``Task.motion_hash``: not the old motion of a task re-authored since) and the same
controller reference mode (a CMRT belongs to its mode), optionally of one kind (plain or robust), only
successes, only for the same clip length (a CMRT's knots are placed on its clip).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from cmrt import inputs
from cmrt.errors import CmrtError
from cmrt.inputs import shown
from cmrt.motion.curve import Cmrt
from cmrt.motion.footsteps import steps_from_tables
from cmrt.motion.library import KnownCmrt, library_cmrts, library_curve
from cmrt.motion.task import Task
from cmrt.service.query import run_curve, task_of
from cmrt.service.store import Run, Store, open_store

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
                     speed=run.speed, steps=steps_from_tables(run.task_definition.get("steps") or [], f"run {run.id}"),
                     motion=task_of(run).motion_hash())


def known_cmrts(task: Task, store: Store | None = None, sources: tuple[str, ...] = SOURCES,
                robust: bool | None = None, same_clip: bool = True) -> list[KnownCmrt]:
    """The successful CMRTs of ``task``'s name and reference mode: the store's finished runs (oldest first),
    then the library's entries (in file order). ``robust``: only that kind (None: both); ``same_clip``: only
    those for the task's clip length."""
    found: list[KnownCmrt] = []
    if "store" in sources and store is not None:
        for run in store.successful_runs(task.name, task.reference_mode):
            try:
                found.append(run_cmrt(run))
            except CmrtError:  # a stored definition that no longer reads as a task: not a CMRT known for this one
                continue
    if "library" in sources:
        found += [e for e in library_cmrts() if e.task == task.name and e.reference == task.reference_mode
                  and e.success]
    motion = task.motion_hash()  # a CMRT of another motion under this name (a re-authored task) is not its
    return [k for k in found if (robust is None or k.robust == robust) and k.motion == motion
            and (not same_clip or abs(k.clip_s - task.clip_s) <= CLIP_TOLERANCE_S)]


CURVE_SPECS = "zero, library, library-robust, a run id or a CMRT .json file"


def resolve_curve(spec: str, task: Task, store_path: str | os.PathLike | None = None,
                  flag: str = "--curve", other_task: bool = False) -> tuple[Cmrt, str]:
    """The CMRT a user names for ``task`` -> (curve, description): ``zero``, ``library``, ``library-robust``,
    a stored run's id (its best; the store at ``store_path`` is opened read-only) or a CMRT ``.json`` file.
    It must be for the task's clip length, and - a stored run's, or a file that names its task (``cmrt
    interpolate`` writes the name) - for the same task unless ``other_task`` (the CLI's ``--force``): a
    bend's CMRT has the punch's clip length but means nothing for it. ``flag`` names the argument in errors."""
    made_for = None  # the task the CMRT was made for, where that is known
    if spec == "zero":
        return Cmrt.zero(task.clip_s), "zero"
    if spec in ("library", "library-robust"):
        curve, what = library_curve(task, robust=spec == "library-robust"), f"the {spec} CMRT of '{task.name}'"
        name = spec
    elif inputs.is_run_id(spec):  # ASCII digits only: str.isdigit() takes '²' too
        run_id = inputs.RUN_ID.check(spec, f"{flag} RUN")
        with open_store(store_path, readonly=True) as store:
            curve = run_curve(store, run_id)
            made_for = store.run(run_id).task
        what = name = f"run {spec}"
    elif Path(spec).suffix.lower() == ".json" or os.path.lexists(spec):
        curve, what, name = Cmrt.load(Path(spec)), f"CMRT in {shown(spec)}", str(Path(spec))
        made_for = _file_task(spec)
    else:
        raise CmrtError(f"{flag} must be {CURVE_SPECS}, got {shown(spec)}")
    if made_for is not None and made_for != task.name and not other_task:
        raise CmrtError(f"{what} was made for task {shown(made_for)}, not {shown(task.name)} "
                        "(add --force to use it anyway)")
    if abs(curve.clip_s - task.clip_s) > CLIP_TOLERANCE_S:  # e.g. the library's entry for the file's own clip
        raise CmrtError(f"{what} is for a {curve.clip_s:g} s clip, task clip is {task.clip_s:g} s")
    return curve, name


def _file_task(path: str) -> str | None:
    """The task a CMRT file names (``cmrt interpolate`` writes ``"task"``); None for a bare CMRT."""
    obj = inputs.parse_json(inputs.read_text(path, "CMRT file"), f"CMRT file {shown(path)}")
    task = obj.get("task") if isinstance(obj, dict) else None
    return task if isinstance(task, str) else None
