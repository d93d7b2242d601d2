"""Task files (TOML) -> a validated :class:`~cmrt.motion.task.Task`.

The shipped tasks are package data (``cmrt/motion/tasks/*.toml``, read through ``importlib.resources`` so an
installed cmrt has them too); a user's own task is a TOML file given by path (format:
docs/reference/task-files.md). Every value is checked (type, finiteness, documented range: ``cmrt.inputs``)
and an error is one line naming the file; a stored run's definition (``Task.to_dict``) goes through the
same ``task_from_dict``.
"""

from __future__ import annotations

import importlib.resources
import math
from dataclasses import replace
from pathlib import Path

from cmrt import inputs
from cmrt.body.character import BODIES, SIDED_JOINTS, feet_flat_qpos, joint_angles_from_pose
from cmrt.body.props import PROPS, prop_class
from cmrt.errors import CmrtError
from cmrt.inputs import POSE_DEG, param_range, shown
from cmrt.modes import DEFAULT_REFERENCE_MODE
from cmrt.motion.ensemble import RobustSpec
from cmrt.motion.footsteps import PlannedStep, parse_steps, steps_from_tables
from cmrt.motion.task import (
    DEFAULT_PARAMS,
    DEFAULTS_3D,
    PARAMS_3D,
    PROPS_3D,
    Task,
    params_off_3d,
    reference_mode,
)

#: The shipped task files (package data: present in an installed cmrt, not only in a checkout).
TASKS_DIR = importlib.resources.files("cmrt.motion") / "tasks"


def available_tasks() -> list[str]:
    """Names of the tasks shipped with cmrt (``load_task(name)`` loads each)."""
    return sorted(f.name.removesuffix(".toml") for f in TASKS_DIR.iterdir() if f.name.endswith(".toml"))


def load_task(name_or_path: str) -> Task:
    """Load a shipped task by name (``bend``) or a user's task file by path (anything ending in ``.toml``): a
    regular UTF-8 file of at most ``cmrt.inputs.MAX_FILE_BYTES`` (``cmrt.inputs.read_text``)."""
    if not isinstance(name_or_path, str) or not name_or_path:
        raise CmrtError(f"a task is a shipped task's name or a .toml file, got {shown(name_or_path)}")
    path = Path(name_or_path)
    if path.suffix != ".toml":
        if name_or_path not in available_tasks():
            raise CmrtError(f"unknown task {shown(name_or_path)} (known: {', '.join(available_tasks())})")
        raw = inputs.parse_toml((TASKS_DIR / f"{name_or_path}.toml").read_text(), f"task file {name_or_path}.toml")
        path = Path(str(TASKS_DIR / f"{name_or_path}.toml"))
    else:
        raw = inputs.load_toml(path, "task file")
    return task_from_dict(raw, source=str(path), default_name=path.stem)


#: The keys of a task file (docs/reference/task-files.md).
TASK_KEYS = frozenset({"name", "summary", "speed_param", "balance_joint", "params", "param_ranges", "start_pose_deg",
                       "end_pose_deg", "via_pose_deg", "timing", "prop", "robust", "reference", "steps",
                       "body", "cmrt_axes"})
MAX_TEXT = 1000  # characters of a task's name or summary


def resolve_task(name_or_path: str, speed: float | None = None, params: dict[str, object] | None = None,
                 reference: str | None = None, steps: str | tuple[PlannedStep, ...] | None = None) -> Task:
    """A task by name or path with its reference mode, parameter overrides (``Task.with_params``: values as
    numbers or their text), speed and footsteps (``--steps`` text or a plan) applied in that order, each
    validated: what the CLI's task arguments and the tools build."""
    task = _resolve(name_or_path, speed, params, reference)
    if steps is None:
        return task
    try:
        return task.with_steps(parse_steps(steps) if isinstance(steps, str) else steps)
    except CmrtError as exc:
        raise CmrtError(str(exc) if str(exc).startswith("--steps") else f"--steps: {exc}") from None


def _resolve(name_or_path: str, speed: float | None, params: dict[str, object] | None,
             reference: str | None) -> Task:
    task = load_task(name_or_path).with_reference(reference)
    if speed is not None and params and task.speed_param in params:  # one would silently override the other
        raise CmrtError(f"--speed sets {task.speed_param}: give --speed or --set {task.speed_param}=..., not both")
    if params:
        try:
            task = task.with_params(**params)
        except CmrtError as exc:
            raise CmrtError(f"--set: {exc}") from None
    try:
        return task.with_speed(speed)
    except CmrtError as exc:
        raise CmrtError(f"--speed: {exc}") from None


def _body(raw: dict, where: str) -> str:
    """The task's ``body`` (default "planar")."""
    body = raw.get("body", "planar")
    if not isinstance(body, str) or body not in BODIES:
        raise CmrtError(f"{where}: body must be one of {', '.join(BODIES)}, got {shown(body)}")
    return body


def _checked_3d(task: Task, where: str) -> Task:
    """A 3D task validated: it stands, pushed or not, lifts a foot, or changes its pose sagittally (docs/body3d.md) -
    no footsteps or timing, no via pose or prop but in a pose change (one of ``PROPS_3D``: a ball to catch, a slab
    to push), no parameter but ``PARAMS_3D``, ``via_fraction`` and that prop's off its default (a robust ensemble's
    table is its own: ``cmrt.sim.clip3d.perturbed_3d`` plays its members), its
    speed (if any) T - in a standing pose the 3D body can take (feet flat, the CoM over them); a pose change's
    poses name the planar body's joints (its reference is the planar one's, ``cmrt.body.sagittal``)."""
    task = replace(task, params={**DEFAULTS_3D, **task.params})
    task = task.with_robust(task.robust.enabled) if task.robust.enabled else task  # a push of its own: refused
    held = task.prop in PROPS_3D and task.end_pose_deg is not None  # a pose change may hold a 3D prop
    via = None if task.end_pose_deg is not None else task.via_pose_deg  # a pose change may pass through one
    standing = task.end_pose_deg is None and not task.params.get("stance_side")
    others = [key for key, value in (("via_pose_deg", via), ("prop", None if held else task.prop),
                                     ("cmrt_axes 2", standing and task.cmrt_axes == 2),
                                     ("steps", task.steps), ("timing", task.timing)) if value]
    others += params_off_3d(task.params, task.prop)
    if task.speed_param not in (None, "duration_s"):
        others.append(f"speed_param {task.speed_param}")
    if others:
        raise CmrtError(f"{where}: a {task.body} task stands, lifts a foot or changes its pose for now "
                        f"(docs/body3d.md): it sets the parameters {', '.join(sorted(PARAMS_3D))}, its poses and "
                        f"its reference, not {', '.join(others)}")
    try:
        task.validate()
        if task.end_pose_deg is not None:
            joint_angles_from_pose({k: 0.0 for k in {**task.start_pose_deg, **task.end_pose_deg}})  # planar names
            task.end_qpos()
        feet_flat_qpos(joint_angles_from_pose({k: math.radians(v) for k, v in task.start_pose_deg.items()},
                                              task.body), body=task.body)
    except CmrtError as exc:
        raise CmrtError(f"{where}: {exc}") from None
    return task


def _table(raw: dict, key: str, where: str) -> dict | None:
    """``raw[key]`` if it is a table (None if absent); CmrtError naming the file and the key otherwise."""
    if key not in raw:
        return None
    value = raw[key]
    if not isinstance(value, dict):
        raise CmrtError(f"{where}: [{key}] must be a table, got {shown(value)}")
    return value


def _text(raw: dict, key: str, where: str, default: str) -> str:
    value = raw.get(key, default)
    if not isinstance(value, str) or len(value) > MAX_TEXT:
        raise CmrtError(f"{where}: {key} must be a string of at most {MAX_TEXT} characters, got {shown(value)}")
    return value


def _pose(table: dict | None, key: str, where: str) -> dict[str, float] | None:
    if table is None:
        return None
    return {str(k): inputs.number(v, f"{where}: {key}.{k}", POSE_DEG, text=False) for k, v in table.items()}


def _pair(value: object, where: str) -> tuple[float, float] | None:
    """``[a, b]`` of two finite numbers (not booleans), or None."""
    if not (isinstance(value, list) and len(value) == 2):
        return None
    try:
        return inputs.number(value[0], where, text=False), inputs.number(value[1], where, text=False)
    except CmrtError:
        return None


def task_from_dict(raw: dict, source: str = "<dict>", default_name: str = "task") -> Task:
    """A task from a task-file dict (TOML, or a stored run's definition), validated: every value of the right
    type, finite and in its documented range (``cmrt.inputs``); errors are one line naming ``source``."""
    where = shown(source, 120).strip("'")
    if not isinstance(raw, dict):
        raise CmrtError(f"{where}: a task definition must be a table, got {shown(raw)}")
    unknown = set(raw) - TASK_KEYS
    if unknown:
        raise CmrtError(f"{where}: unknown key(s) {', '.join(shown(k) for k in sorted(map(str, unknown)))}")
    body = _body(raw, where)
    params = dict(DEFAULT_PARAMS)
    prop = None
    prop_table = _table(raw, "prop", where)
    if prop_table is not None:
        prop = prop_table.get("kind")
        if set(prop_table) - {"kind"} or not isinstance(prop, str) or prop not in PROPS:
            raise CmrtError(f"{where}: prop.kind must be one of {', '.join(PROPS)} (and [prop] nothing else), got "
                            f"{shown(prop_table)}")
        params.update(PROPS[prop].PARAMS)
    limits = prop_class(prop).LIMITS
    for key, value in (_table(raw, "params", where) or {}).items():
        inputs.param_name(key, f"{where}: a key of [params]")
        params[key] = inputs.number(value, f"{where}: parameter {key}", param_range(key, limits), text=False)
    ranges = {}
    for key, value in (_table(raw, "param_ranges", where) or {}).items():
        pair = _pair(value, where)
        if key not in params or pair is None or not pair[0] <= pair[1]:
            raise CmrtError(f"{where}: param_ranges.{shown(key).strip(chr(39))} must be [low, high] (finite, "
                            f"low <= high) of a known parameter, got {shown(value)}")
        ranges[key] = pair
    speed_param = raw.get("speed_param")
    if speed_param is not None and (not isinstance(speed_param, str) or speed_param not in params):
        raise CmrtError(f"{where}: speed_param must name a parameter, got {shown(speed_param)}")
    balance_joint = raw.get("balance_joint", "ankle")
    if balance_joint is None:
        balance_joint = ""
    if not isinstance(balance_joint, str) or balance_joint not in ("", *SIDED_JOINTS):
        raise CmrtError(f"{where}: balance_joint must be one of {', '.join(SIDED_JOINTS)} or \"\", "
                        f"got {shown(balance_joint)}")
    poses = {key: _pose(_table(raw, key, where), key, where) for key in ("start_pose_deg", "end_pose_deg",
                                                                          "via_pose_deg")}
    timing = {}
    for key, value in (_table(raw, "timing", where) or {}).items():
        pair = _pair(value, where)
        if pair is None or not 0.0 <= pair[0] < pair[1] <= 1.0:
            raise CmrtError(f"{where}: timing.{shown(key).strip(chr(39))} must be [start, end] fractions of T with "
                            f"0 <= start < end <= 1, got {shown(value)}")
        timing[str(key)] = pair
    robust_table = _table(raw, "robust", where)
    task = Task(
        name=_text(raw, "name", where, default_name),
        summary=_text(raw, "summary", where, ""),
        params=params,
        param_ranges=ranges,
        start_pose_deg=poses["start_pose_deg"] or {},
        end_pose_deg=poses["end_pose_deg"],
        via_pose_deg=poses["via_pose_deg"],
        balance_joint=balance_joint or None,
        timing=timing,
        prop=prop,
        speed_param=speed_param,
        source=source,
        robust=RobustSpec.from_table(robust_table, where) if robust_table is not None else RobustSpec(),
        reference_mode=reference_mode(raw.get("reference", DEFAULT_REFERENCE_MODE), f"{where}: reference"),
        steps=steps_from_tables(raw["steps"], where) if "steps" in raw else (),
        body=body,
        cmrt_axes=_cmrt_axes(raw, body, where),
    )
    return _checked_3d(task, where) if body != "planar" else _checked_planar(task, where)


def _cmrt_axes(raw: dict, body: str, where: str) -> int:
    """The task's ``cmrt_axes``: 1 (default), or 2 on the 3D body (a CMRT in x and y, docs/body3d.md)."""
    axes = raw.get("cmrt_axes", 1)
    if type(axes) is not int or axes not in (1, 2):
        raise CmrtError(f"{where}: cmrt_axes must be 1 or 2, got {shown(axes)}")
    if axes == 2 and body == "planar":
        raise CmrtError(f"{where}: cmrt_axes = 2 is for the 3D body (the planar body has one horizontal axis)")
    return axes


def _checked_planar(task: Task, where: str) -> Task:
    """A planar task validated: its parameters, timing joints and poses (unknown joints, unbalanceable poses)."""
    try:
        task.validate()
        joint_angles_from_pose({k: 0.0 for k in task.timing})
        task.start_qpos()
        task.end_qpos()
        if task.via_pose_deg is not None:
            task.via_qpos()
    except CmrtError as exc:
        raise CmrtError(f"{where}: {exc}") from None
    return task
