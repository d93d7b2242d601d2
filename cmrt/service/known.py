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
from cmrt.motion.curve import N_PARAMS, N_PARAMS_TWO_AXES, VALUE_M, Cmrt
from cmrt.motion.footsteps import steps_from_tables
from cmrt.motion.library import KnownCmrt, library_cmrts, library_curve
from cmrt.motion.task import Task
from cmrt.service.query import run_curve, stored_curve, task_of
from cmrt.service.store import Run, Store, open_store

CLIP_TOLERANCE_S = 1e-9
SOURCES = ("store", "library")


#: each of the 8 CMA-ES parameters a start point may have: displacements within +-1 m are +-20 of them, and a
#: knot-gap logit beyond 100 only makes a gap vanish (exp(-100)); 1e308 or NaN would make CMA-ES's samples overflow
START_PARAM = inputs.Range(-100.0, 100.0)


def start_point(params: tuple[float, ...], clip_s: float, where: str, n_params: int | None = None
                ) -> tuple[float, ...]:
    """Stored CMA-ES parameters to start a search from (a run's best copied into a new run, or a queued run's own
    start), held to what a user may give: 8 numbers (12 for a CMRT in two axes) in ``START_PARAM`` whose CMRT a
    curve file may hold (``VALUE_M``). ``n_params``: the searched CMRT's (``Task.n_cmrt_params``; None: as
    stored) - a one-axis CMRT starts a two-axis search with nothing across (its cross values 0). CmrtError naming
    ``where`` otherwise."""
    if len(params) not in (N_PARAMS, N_PARAMS_TWO_AXES) or (n_params == N_PARAMS and len(params) != N_PARAMS):
        want = N_PARAMS if n_params == N_PARAMS else f"{N_PARAMS} or {N_PARAMS_TWO_AXES}"
        raise CmrtError(f"{where}: expected {want} CMRT parameters, got {len(params)}")
    checked = tuple(inputs.number(p, where, START_PARAM, text=False) for p in params)
    Cmrt.from_dict(Cmrt.from_params(np.asarray(checked), clip_s).to_dict(), where, VALUE_M)
    if n_params is not None and len(checked) < n_params:
        checked += (0.0,) * (n_params - len(checked))
    return checked


def run_cmrt(run: Run) -> KnownCmrt:
    """A finished run's best CMRT as a record (its optimizer parameters as stored, bit for bit, and checked as a
    start point; the curve as stored, else made from them)."""
    where = f"run {run.id}'s best CMRT"
    if run.best_params is None or run.best_objective is None:
        raise CmrtError(f"the store is damaged: run {run.id} is done without a best CMRT and objective")
    cma_params = start_point(run.best_params, run.params["clip_s"], where)
    curve = (stored_curve(run) if run.best_cmrt is not None
             else Cmrt.from_params(np.asarray(cma_params), run.params["clip_s"]))
    return KnownCmrt(task=run.task, params=run.params, reference=run.reference, robust=run.robust is not None,
                     curve=curve, cma_params=cma_params,
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
        return Cmrt.zero(task.clip_s, task.cmrt_axes), "zero"
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
