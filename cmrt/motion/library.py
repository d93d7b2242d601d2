"""The CMRTs shipped with the project (``cmrt/motion/library.json``).

``--curve library`` looks a task and speed up here, so users can run the paper's
results without optimizing. Entries are written by ``tools/find_library_curve.py``.

A CMRT known for a task - a library entry here, or a stored run's best (``cmrt.service.known``) - is one
record, :class:`KnownCmrt`, so that warm starts, interpolation and ``--curve library`` read the same thing.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from cmrt.errors import CmrtError
from cmrt.modes import DEFAULT_REFERENCE_MODE
from cmrt.motion.curve import Cmrt
from cmrt.motion.footsteps import parse_steps
from cmrt.motion.task import Task, active_params
from cmrt.motion.taskfile import load_task

LIBRARY_PATH = Path(__file__).parent / "library.json"
SPEED_TOLERANCE = 1e-9


@dataclass(frozen=True)
class KnownCmrt:
    """A CMRT known for a task, from the library or the store, with what it was optimized for."""

    task: str  # the task's name
    params: Mapping[str, float]  # the task parameters it was optimized for (the speed among them)
    reference: str  # the controller's reference mode it belongs to ("center" or "yu")
    robust: bool  # optimized on the task's ensemble of perturbed clips
    curve: Cmrt
    cma_params: tuple[float, ...]  # the optimizer's 8 (or 12) parameters of ``curve`` (a warm start's x0)
    objective: float
    success: bool
    source: str  # "library" or "run 12"
    speed: float | None = None  # the task's speed parameter's value (None: the task has none)
    steps: tuple = ()  # the footstep plan it was optimized for (cmrt.motion.footsteps; () without one)
    motion: str | None = None  # Task.motion_hash of the motion it was optimized for (None: not known)

    @property
    def clip_s(self) -> float:
        return self.curve.clip_s


def load_entries(path: Path = LIBRARY_PATH) -> list[dict]:
    """The shipped library's entries as written (task, speed, params, cmrt, objective, success, robust, ...);
    ``library_cmrts`` reads them as records."""
    if not path.exists():
        return []
    return json.loads(path.read_text())["entries"]


def library_cmrts(path: Path = LIBRARY_PATH) -> list[KnownCmrt]:
    """The library's entries as records, in file order. An entry written before entries carried their
    parameters stands for the task file's defaults at its speed."""
    out = []
    for e in load_entries(path):
        curve = Cmrt.from_dict(e["cmrt"])
        params = e.get("params") or load_task(e["task"]).with_speed(e["speed"]).params
        out.append(KnownCmrt(task=e["task"], params=params, reference=e.get("reference", DEFAULT_REFERENCE_MODE),
                             robust=e.get("robust", False), curve=curve,
                             cma_params=tuple(map(float, curve.to_params())), objective=e["objective"],
                             success=bool(e.get("success")), source="library", speed=e["speed"],
                             steps=parse_steps(e["steps"]) if e.get("steps") else (), motion=e.get("motion")))
    return out


def _physics(params: dict, planned: bool = False) -> dict:
    return {k: v for k, v in active_params(params, planned).items() if k != "stop_threshold"}


def library_curve(task: Task, path: Path = LIBRARY_PATH, robust: bool = False) -> Cmrt:
    """The shipped CMRT for this task at exactly this speed.

    The library holds a plain CMRT (optimized on the nominal clip, as the paper does: the
    default, which the Table 1 reproduction, the speed and mass families and the sequences
    use) and a robust one (optimized on the task's ensemble, ``cmrt.motion.ensemble``: ``robust=True``).
    Other parameters may differ (that is the expectation-mismatch demo: the 7 kg catch
    CMRT used on a 1 kg ball); if several entries share the speed, the one whose
    parameters all match wins, else the one for the task file's defaults.
    """
    entries = [e for e in library_cmrts(path) if e.robust == robust
               and e.reference == task.reference_mode  # a CMRT belongs to its reference mode
               and e.steps == task.steps  # and to its footstep plan
               and e.motion == task.motion_hash()]  # and to its motion (not a re-authored task's old one)
    try:
        return _lookup(entries, task)
    except CmrtError as exc:
        kinds = ["robust CMRTs"] if robust else []
        if task.reference_mode != DEFAULT_REFERENCE_MODE:
            kinds.append(f"reference {task.reference_mode}")
        suffix = f" ({', '.join(kinds)})" if kinds else ""
        raise CmrtError(f"{exc}{suffix}") from None


def _lookup(entries: list[KnownCmrt], task: Task) -> Cmrt:
    same_speed = [e for e in entries if e.task == task.name
                  and (task.speed is None or abs(e.speed - task.speed) <= SPEED_TOLERANCE)]
    planned = bool(task.steps)  # the entries are this plan's (library_curve)
    for entry in same_speed:
        if _physics(entry.params, planned) == _physics(task.params, planned):
            return entry.curve
    if same_speed:  # parameters differ: the entry for the task file's own defaults at this speed
        defaults = (_physics(load_task(task.name).with_speed(task.speed).params, planned) if task.speed is not None
                    else None)
        for entry in same_speed:
            if _physics(entry.params, planned) == defaults:
                return entry.curve
        return same_speed[0].curve
    speeds = sorted({e.speed for e in entries if e.task == task.name})
    have = f" (library has speeds {', '.join(f'{s:g}' for s in speeds)})" if speeds else ""
    raise CmrtError(f"no library CMRT for task '{task.name}' at speed {task.speed}{have}")


def save_entry(entry: dict, path: Path = LIBRARY_PATH) -> None:
    """Insert or replace the entry for (task, motion, parameters), keeping the file sorted; the task's entries
    for another motion (the task re-authored since) are dropped: nothing can use them."""

    def key(e: dict):
        params = e.get("params") or load_task(e["task"]).with_speed(e["speed"]).params  # older entries: defaults
        return (e["task"], e["speed"], json.dumps(_physics(params, bool(e.get("steps"))), sort_keys=True),
                e.get("robust", False), e.get("reference", DEFAULT_REFERENCE_MODE), e.get("steps", ""))

    def stale(e: dict) -> bool:
        return e["task"] == entry["task"] and e.get("motion") != entry.get("motion")

    entries = [e for e in load_entries(path) if key(e) != key(entry) and not stale(e)]
    entries.append(entry)
    entries.sort(key=lambda e: (e["task"], e["speed"], json.dumps(e.get("params", {}), sort_keys=True),
                                e.get("robust", False), e.get("reference", DEFAULT_REFERENCE_MODE)))
    path.write_text(json.dumps({"entries": entries}, indent=2) + "\n")
