"""CMRT: anticipatory balance via optimized center-of-mass reference trajectories.

The public API for scripts; the CLI (``cmrt``) is a thin layer over it::

    import cmrt
    task = cmrt.load_task("bend").with_speed(0.4)
    zero = cmrt.evaluate(task, cmrt.simulate(task))
    lib = cmrt.evaluate(task, cmrt.simulate(task, cmrt.library_curve(task)))
"""

from cmrt.character import character, load_model
from cmrt.control import ControllerConfig, MomentumBalanceController
from cmrt.curve import Cmrt
from cmrt.errors import CmrtError
from cmrt.library import library_curve
from cmrt.objective import Evaluation, evaluate
from cmrt.simulate import Trajectory, simulate
from cmrt.task import Task, available_tasks, load_task

__all__ = [
    "Cmrt",
    "CmrtError",
    "ControllerConfig",
    "Evaluation",
    "MomentumBalanceController",
    "Task",
    "Trajectory",
    "available_tasks",
    "character",
    "evaluate",
    "library_curve",
    "load_model",
    "load_task",
    "simulate",
]
