"""CMRT: anticipatory balance via optimized center-of-mass reference trajectories.

The public API for scripts; the CLI (``cmrt``) is a thin layer over it::

    import cmrt
    task = cmrt.load_task("bend").with_speed(0.4)
    zero = cmrt.evaluate(task, cmrt.simulate(task))
    lib = cmrt.evaluate(task, cmrt.simulate(task, cmrt.library_curve(task)))
    with cmrt.open_store("store/cmrt.sqlite") as store:
        run = cmrt.optimize_now(store, task, seed=1)
"""

import importlib
import os as _os
import sys
import types
from typing import TYPE_CHECKING

# The controller's matrices are tiny: BLAS thread pools only add overhead and, with
# several worker processes, oversubscription. Effective only if numpy is not loaded yet.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")

# Offscreen rendering backend, read by mujoco at import: EGL where a GPU device exists,
# else OSMesa (software). A user's MUJOCO_GL wins. Failures surface only when rendering.
if "MUJOCO_GL" not in _os.environ:
    _gpu = _os.path.exists("/dev/nvidia0") or any(_os.path.exists(f"/dev/dri/renderD{i}") for i in range(128, 136))
    _os.environ["MUJOCO_GL"] = "egl" if _gpu else "osmesa"

# The API is imported on first use (PEP 562), so that ``import cmrt`` - and the ``cmrt`` command's start,
# which a Ctrl-C may interrupt - does not load MuJoCo, numba and dask up front. Type checkers and IDEs see
# the imports below.
if TYPE_CHECKING:
    from cmrt.balance import BalanceLimits, FallReason
    from cmrt.character import character, load_model
    from cmrt.control import ControllerConfig, MomentumBalanceController
    from cmrt.curve import Cmrt
    from cmrt.ensemble import Perturbation, RobustSpec
    from cmrt.errors import CmrtError
    from cmrt.interpolate import interpolate, superpose
    from cmrt.jobs import claim, optimize_family, optimize_now, submit, work
    from cmrt.library import library_curve
    from cmrt.objective import Evaluation, evaluate
    from cmrt.optimize import OptimizeSettings
    from cmrt.parallel import Evaluator
    from cmrt.query import best_run, export_run, run_curve, run_details, task_of
    from cmrt.sequence import load_sequence
    from cmrt.simulate import Trajectory, simulate
    from cmrt.store import Generation, Run, Store, StoredEvaluation, open_store
    from cmrt.task import Task, available_tasks, load_task
    from cmrt.validate import robustness
    from cmrt.warmstart import nearest_start

_API = {
    "BalanceLimits": "cmrt.balance",
    "Cmrt": "cmrt.curve",
    "CmrtError": "cmrt.errors",
    "ControllerConfig": "cmrt.control",
    "Evaluation": "cmrt.objective",
    "Evaluator": "cmrt.parallel",
    "FallReason": "cmrt.balance",
    "Generation": "cmrt.store",
    "MomentumBalanceController": "cmrt.control",
    "OptimizeSettings": "cmrt.optimize",
    "Perturbation": "cmrt.ensemble",
    "RobustSpec": "cmrt.ensemble",
    "Run": "cmrt.store",
    "Store": "cmrt.store",
    "StoredEvaluation": "cmrt.store",
    "Task": "cmrt.task",
    "Trajectory": "cmrt.simulate",
    "available_tasks": "cmrt.task",
    "best_run": "cmrt.query",
    "character": "cmrt.character",
    "claim": "cmrt.jobs",
    "evaluate": "cmrt.objective",
    "export_run": "cmrt.query",
    "interpolate": "cmrt.interpolate",
    "library_curve": "cmrt.library",
    "load_model": "cmrt.character",
    "load_sequence": "cmrt.sequence",
    "load_task": "cmrt.task",
    "nearest_start": "cmrt.warmstart",
    "open_store": "cmrt.store",
    "optimize_family": "cmrt.jobs",
    "optimize_now": "cmrt.jobs",
    "robustness": "cmrt.validate",
    "run_curve": "cmrt.query",
    "run_details": "cmrt.query",
    "simulate": "cmrt.simulate",
    "submit": "cmrt.jobs",
    "superpose": "cmrt.interpolate",
    "task_of": "cmrt.query",
    "work": "cmrt.jobs",
}


def __getattr__(name: str):
    module = _API.get(name)
    if module is None:
        try:  # a submodule: cmrt.jobs, cmrt.plot, ...
            return importlib.import_module(f"cmrt.{name}")
        except ModuleNotFoundError:
            raise AttributeError(f"module 'cmrt' has no attribute '{name}'") from None
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API))


class _Package(types.ModuleType):
    """``cmrt.simulate`` and ``cmrt.interpolate`` are API functions with the names of their modules. Importing
    a submodule binds it on the package; for these names the function wins, as it did with eager imports."""

    def __setattr__(self, name: str, value) -> None:
        if name in _API and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package


__all__ = [
    "BalanceLimits",
    "Cmrt",
    "CmrtError",
    "ControllerConfig",
    "Evaluation",
    "Evaluator",
    "FallReason",
    "Generation",
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
    "claim",
    "evaluate",
    "export_run",
    "interpolate",
    "library_curve",
    "load_model",
    "load_sequence",
    "load_task",
    "nearest_start",
    "open_store",
    "optimize_family",
    "optimize_now",
    "robustness",
    "run_curve",
    "run_details",
    "simulate",
    "submit",
    "superpose",
    "task_of",
    "work",
]
