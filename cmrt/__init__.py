"""CMRT: anticipatory balance via optimized center-of-mass reference trajectories.

The public API for scripts; the CLI (``cmrt``) is a thin layer over it::

    import cmrt
    task = cmrt.load_task("bend").with_speed(0.4)
    zero = cmrt.evaluate(task, cmrt.simulate(task))
    lib = cmrt.evaluate(task, cmrt.simulate(task, cmrt.library_curve(task)))
    with cmrt.open_store("store/cmrt.sqlite") as store:
        run = cmrt.optimize_now(store, task, seed=1)
"""

import os as _os

# The controller's matrices are tiny: BLAS thread pools only add overhead and, with
# several worker processes, oversubscription. Effective only if numpy is not loaded yet.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")

# Offscreen rendering backend, read by mujoco at import: EGL where a GPU device exists,
# else OSMesa (software). A user's MUJOCO_GL wins. Failures surface only when rendering.
if "MUJOCO_GL" not in _os.environ:
    _gpu = _os.path.exists("/dev/nvidia0") or any(_os.path.exists(f"/dev/dri/renderD{i}") for i in range(128, 136))
    _os.environ["MUJOCO_GL"] = "egl" if _gpu else "osmesa"

from cmrt.balance import BalanceLimits, FallReason  # noqa: E402
from cmrt.character import character, load_model  # noqa: E402
from cmrt.control import ControllerConfig, MomentumBalanceController  # noqa: E402
from cmrt.curve import Cmrt  # noqa: E402
from cmrt.ensemble import Perturbation, RobustSpec  # noqa: E402
from cmrt.errors import CmrtError  # noqa: E402
from cmrt.interpolate import interpolate, superpose  # noqa: E402
from cmrt.jobs import claim, optimize_family, optimize_now, submit, work  # noqa: E402
from cmrt.library import library_curve  # noqa: E402
from cmrt.objective import Evaluation, evaluate  # noqa: E402
from cmrt.optimize import OptimizeSettings  # noqa: E402
from cmrt.parallel import Evaluator  # noqa: E402
from cmrt.query import best_run, export_run, run_curve, run_details, task_of  # noqa: E402
from cmrt.sequence import load_sequence  # noqa: E402
from cmrt.simulate import Trajectory, simulate  # noqa: E402
from cmrt.store import Generation, Run, Store, StoredEvaluation, open_store  # noqa: E402
from cmrt.task import Task, available_tasks, load_task  # noqa: E402
from cmrt.validate import robustness  # noqa: E402
from cmrt.warmstart import nearest_start  # noqa: E402

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
