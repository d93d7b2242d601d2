"""CMRT: anticipatory balance via optimized center-of-mass reference trajectories.

The public API for scripts; the CLI (``cmrt``) is a thin layer over it::

    import cmrt
    task = cmrt.load_task("bend").with_speed(0.4)
    print(cmrt.check_reference(task).feasible)   # can its keyed motion be done at all?
    zero = cmrt.evaluate(task, cmrt.simulate(task))
    lib = cmrt.evaluate(task, cmrt.simulate(task, cmrt.library_curve(task)))
    with cmrt.open_store("store/cmrt.sqlite") as store:
        run = cmrt.optimize_now(store, task, seed=1)
"""

import importlib as _importlib
import os as _os
import sys as _sys
from importlib.metadata import PackageNotFoundError as _PackageNotFoundError
from importlib.metadata import version as _version
from typing import TYPE_CHECKING as _TYPE_CHECKING

try:
    __version__ = _version("cmrt")
except _PackageNotFoundError:  # run from a source tree that was never installed
    __version__ = "0+unknown"

# The controller's matrices are tiny: BLAS thread pools only add overhead and, with
# several worker processes, oversubscription. Effective only if numpy is not loaded yet.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")

# OpenGL only when rendering. MuJoCo loads the backend MUJOCO_GL names when it is imported, and a backend that
# cannot load (no libOSMesa, no EGL driver) breaks that import - every command, not only rendering. So cmrt has
# MuJoCo imported with GL disabled and loads the backend itself when it renders (cmrt.viz.render), keeping the
# user's MUJOCO_GL in CMRT_MUJOCO_GL. A script that imported mujoco before cmrt keeps mujoco's own choice.
if "mujoco" not in _sys.modules:
    _os.environ.setdefault("CMRT_MUJOCO_GL", _os.environ.get("MUJOCO_GL", ""))
    _os.environ["MUJOCO_GL"] = "disable"

# The API is imported on first use (PEP 562), so that ``import cmrt`` - and the ``cmrt`` command's start,
# which a Ctrl-C may interrupt - does not load MuJoCo, numba and dask up front. Type checkers and IDEs see
# the imports below.
if _TYPE_CHECKING:
    from cmrt.body.character import character, load_model
    from cmrt.control import ControllerConfig, MomentumBalanceController
    from cmrt.errors import CmrtError
    from cmrt.motion.curve import Cmrt
    from cmrt.motion.ensemble import Perturbation, RobustSpec
    from cmrt.motion.feasibility import Feasibility, check_reference
    from cmrt.motion.library import KnownCmrt, library_curve
    from cmrt.motion.sequence import load_sequence
    from cmrt.motion.task import Task
    from cmrt.motion.taskfile import available_tasks, load_task, resolve_task
    from cmrt.optimize.parallel import Evaluator
    from cmrt.optimize.settings import OptimizeSettings
    from cmrt.service.interpolate import interpolate, superpose
    from cmrt.service.jobs import claim, optimize_family, optimize_now, submit, work
    from cmrt.service.known import known_cmrts, resolve_curve
    from cmrt.service.query import best_run, export_run, run_curve, run_details, task_of
    from cmrt.service.store import Generation, Run, Store, StoredEvaluation, open_store
    from cmrt.service.warmstart import nearest_start
    from cmrt.sim.balance import BalanceLimits, FallReason
    from cmrt.sim.objective import Evaluation
    from cmrt.sim.report import evaluate, evaluation_dict, save_trace, sequence_report, simulate, simulate_report
    from cmrt.sim.simulate import Trajectory
    from cmrt.sim.validate import robustness

_API = {
    "BalanceLimits": "cmrt.sim.balance",
    "Cmrt": "cmrt.motion.curve",
    "CmrtError": "cmrt.errors",
    "ControllerConfig": "cmrt.control",
    "Evaluation": "cmrt.sim.objective",
    "Evaluator": "cmrt.optimize.parallel",
    "Feasibility": "cmrt.motion.feasibility",
    "FallReason": "cmrt.sim.balance",
    "Generation": "cmrt.service.store",
    "KnownCmrt": "cmrt.motion.library",
    "MomentumBalanceController": "cmrt.control",
    "OptimizeSettings": "cmrt.optimize.settings",
    "Perturbation": "cmrt.motion.ensemble",
    "RobustSpec": "cmrt.motion.ensemble",
    "Run": "cmrt.service.store",
    "Store": "cmrt.service.store",
    "StoredEvaluation": "cmrt.service.store",
    "Task": "cmrt.motion.task",
    "Trajectory": "cmrt.sim.simulate",
    "available_tasks": "cmrt.motion.taskfile",
    "best_run": "cmrt.service.query",
    "character": "cmrt.body.character",
    "check_reference": "cmrt.motion.feasibility",
    "claim": "cmrt.service.jobs",
    "evaluate": "cmrt.sim.report",
    "evaluation_dict": "cmrt.sim.report",
    "export_run": "cmrt.service.query",
    "interpolate": "cmrt.service.interpolate",
    "known_cmrts": "cmrt.service.known",
    "library_curve": "cmrt.motion.library",
    "load_model": "cmrt.body.character",
    "load_sequence": "cmrt.motion.sequence",
    "load_task": "cmrt.motion.taskfile",
    "nearest_start": "cmrt.service.warmstart",
    "open_store": "cmrt.service.store",
    "optimize_family": "cmrt.service.jobs",
    "optimize_now": "cmrt.service.jobs",
    "resolve_curve": "cmrt.service.known",
    "resolve_task": "cmrt.motion.taskfile",
    "robustness": "cmrt.sim.validate",
    "run_curve": "cmrt.service.query",
    "run_details": "cmrt.service.query",
    "save_trace": "cmrt.sim.report",
    "sequence_report": "cmrt.sim.report",
    "simulate": "cmrt.sim.report",
    "simulate_report": "cmrt.sim.report",
    "submit": "cmrt.service.jobs",
    "superpose": "cmrt.service.interpolate",
    "task_of": "cmrt.service.query",
    "work": "cmrt.service.jobs",
}


def __getattr__(name: str):
    module = _API.get(name)
    if module is None:
        try:  # a layer package: cmrt.service, cmrt.viz, ...
            return _importlib.import_module(f"cmrt.{name}")
        except ModuleNotFoundError:
            raise AttributeError(f"module 'cmrt' has no attribute '{name}'") from None
    value = getattr(_importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    """The public API (``__all__``) and the module's dunders: not the names it uses to load them."""
    return sorted(set(__all__) | {n for n in globals() if n.startswith("__")})


__all__ = [
    "BalanceLimits",
    "Cmrt",
    "CmrtError",
    "ControllerConfig",
    "Evaluation",
    "Evaluator",
    "Feasibility",
    "FallReason",
    "Generation",
    "KnownCmrt",
    "MomentumBalanceController",
    "OptimizeSettings",
    "Perturbation",
    "RobustSpec",
    "Run",
    "Store",
    "StoredEvaluation",
    "Task",
    "Trajectory",
    "available_tasks",
    "best_run",
    "character",
    "check_reference",
    "claim",
    "evaluate",
    "evaluation_dict",
    "export_run",
    "interpolate",
    "known_cmrts",
    "library_curve",
    "load_model",
    "load_sequence",
    "load_task",
    "nearest_start",
    "open_store",
    "optimize_family",
    "optimize_now",
    "resolve_curve",
    "resolve_task",
    "robustness",
    "run_curve",
    "run_details",
    "save_trace",
    "sequence_report",
    "simulate",
    "simulate_report",
    "submit",
    "superpose",
    "task_of",
    "work",
]
