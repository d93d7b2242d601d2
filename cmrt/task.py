"""Task files (TOML) -> reference motion, push, clip timing, objective settings.

A task is data, not code. The shipped tasks are package data (``cmrt/tasks/*.toml``,
read through ``importlib.resources`` so an installed cmrt has them too); a user's own
task is a TOML file given by path (format in the README). Every number lives in ``[params]`` so that
``--set KEY=VALUE`` can override any of them; poses are tables of joint angles in
degrees.
"""

from __future__ import annotations

import hashlib
import importlib.resources
import json
import math
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from cmrt import reference as ref
from cmrt.character import character, feet_flat_qpos, joint_angles_from_pose
from cmrt.ensemble import RobustSpec
from cmrt.errors import CmrtError
from cmrt.props import PROPS, build_model, model_values

MIN_TAIL_S = 0.5
#: The shipped task files (package data: present in an installed cmrt, not only in a checkout).
TASKS_DIR = importlib.resources.files("cmrt") / "tasks"

#: Parameters every task has, with defaults (seconds, newtons, metres).
DEFAULT_PARAMS: dict[str, float] = {
    "clip_s": 2.6,  # L: whole clip
    "preparation_s": 1.0,  # P: standing before the motion starts
    "duration_s": 0.0,  # T: duration of the pose change (0: no pose change)
    "cop_sample_step_s": 0.01,  # step of the CoP-error samples in the objective
    "stop_threshold": 0.0,  # CMA-ES early-stop threshold on the objective (ABC Table 1)
    "push_force_n": 0.0,  # horizontal push on the thorax, +x forward
    "push_start_s": 0.0,
    "push_duration_s": 0.0,
    # the motion was performed if tracked over [P, P + T] at least as well as its own reference played
    # this fraction of T late (RMS over the actuated joints; 0.1 of T: ~0.1 rad on the bend)
    "max_tracking_lag": 0.1,
    "tail_s": 0.5,  # standing after the clip (end pose held, no CMRT): must settle; not in the CoP objective
}


@dataclass(frozen=True)
class Task:
    """A task: its parameters (a mapping, so ``--set`` reaches every number), poses, timing, prop and robust
    ensemble. Immutable: ``with_params``/``with_speed``/``with_robust`` return validated copies."""

    name: str
    summary: str
    params: dict[str, float]
    param_ranges: dict[str, tuple[float, float]] = field(default_factory=dict)
    start_pose_deg: dict[str, float] = field(default_factory=dict)
    end_pose_deg: dict[str, float] | None = None
    via_pose_deg: dict[str, float] | None = None  # optional pose passed through at via_fraction of T
    balance_joint: str | None = "ankle"
    timing: dict[str, tuple[float, float]] = field(default_factory=dict)
    prop: str | None = None
    speed_param: str | None = None
    source: str = ""
    robust: RobustSpec = RobustSpec()  # the [robust] table: the ensemble a robust run is scored on

    # --- parameters -------------------------------------------------------------
    # Those every task has (DEFAULT_PARAMS) as typed properties; any other (a prop's, via_fraction) is read
    # from the mapping: ``task.params["ball_mass_kg"]``.
    @property
    def clip_s(self) -> float:
        """L: the whole clip (s)."""
        return self.params["clip_s"]

    @property
    def preparation_s(self) -> float:
        """P: standing before the motion starts (s)."""
        return self.params["preparation_s"]

    @property
    def duration_s(self) -> float:
        """T: duration of the pose change (s; 0: no pose change)."""
        return self.params["duration_s"]

    @property
    def cop_sample_step_s(self) -> float:
        """Step of the CoP-error samples in the objective (s)."""
        return self.params["cop_sample_step_s"]

    @property
    def stop_threshold(self) -> float:
        """CMA-ES early-stop threshold on the objective (objective units; ABC Table 1)."""
        return self.params["stop_threshold"]

    @property
    def push_force_n(self) -> float:
        """Horizontal push on the thorax (N, +x forward)."""
        return self.params["push_force_n"]

    @property
    def push_start_s(self) -> float:
        """When the push starts (s from the start of the clip)."""
        return self.params["push_start_s"]

    @property
    def push_duration_s(self) -> float:
        """How long the push lasts (s)."""
        return self.params["push_duration_s"]

    @property
    def max_tracking_lag(self) -> float:
        """Largest tracking lag that still counts as the motion performed (a fraction of T, dimensionless)."""
        return self.params["max_tracking_lag"]

    @property
    def tail_s(self) -> float:
        """Standing after the clip, end pose held without a CMRT (s; not in the CoP objective)."""
        return self.params["tail_s"]

    @property
    def speed(self) -> float | None:
        """The value of the task's speed parameter (None if it has none)."""
        return self.params[self.speed_param] if self.speed_param else None

    @property
    def decay_s(self) -> float:
        """D = L - P - T: the clip after the motion (s)."""
        return self.clip_s - self.preparation_s - self.duration_s

    def with_params(self, **overrides: float) -> Task:
        """A copy with parameters overridden (validated against names and ranges)."""
        params = dict(self.params)
        for key, value in overrides.items():
            if key not in params:
                raise CmrtError(f"task '{self.name}' has no parameter '{key}' (has: {', '.join(sorted(params))})")
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise CmrtError(f"parameter '{key}' must be a number, got '{value}'") from None
            if not math.isfinite(value):
                raise CmrtError(f"parameter '{key}' must be finite, got '{value}'")
            params[key] = value
        task = replace(self, params=params)
        task.validate()
        return task

    def with_robust(self, enabled: bool = True) -> Task:
        """A copy scored on its robust ensemble (``cmrt.ensemble``), or on the nominal clip alone."""
        return replace(self, robust=replace(self.robust, enabled=enabled))

    def with_speed(self, speed: float | None) -> Task:
        """A copy at this speed (None: unchanged)."""
        if speed is None:
            return self
        if not self.speed_param:
            raise CmrtError(f"task '{self.name}' has no speed parameter")
        return self.with_params(**{self.speed_param: speed})

    def validate(self) -> None:
        """CmrtError if a parameter is out of its range or the timing is impossible."""
        p = self.params
        for key, (lo, hi) in self.param_ranges.items():
            if not lo <= p[key] <= hi:
                raise CmrtError(f"{key} = {p[key]:g} is outside task '{self.name}' range [{lo:g}, {hi:g}]")
        if p["clip_s"] <= 0 or p["preparation_s"] < 0 or p["duration_s"] < 0:
            raise CmrtError("clip_s must be > 0, preparation_s and duration_s >= 0")
        if self.decay_s < -1e-12:
            raise CmrtError(f"preparation_s + duration_s exceeds clip_s ({p['clip_s']:g} s)")
        if self.end_pose_deg is not None and p["duration_s"] <= 0:
            raise CmrtError("a pose-change task needs duration_s > 0")
        if self.via_pose_deg is not None:
            if self.end_pose_deg is None or self.timing:
                raise CmrtError("a via pose needs an end pose and no [timing] (each segment eases as a whole)")
            if not 0.0 < p.get("via_fraction", -1.0) < 1.0:
                raise CmrtError("a via pose needs via_fraction in (0, 1) in [params]")
        if p["cop_sample_step_s"] <= 0:
            raise CmrtError("cop_sample_step_s must be > 0")
        if not 0 < p["max_tracking_lag"] <= 1:
            raise CmrtError("max_tracking_lag must be in (0, 1] (a fraction of duration_s)")
        if p["tail_s"] < MIN_TAIL_S:
            raise CmrtError(f"tail_s must be >= {MIN_TAIL_S:g} s (the character must be seen standing still)")
        if p["push_duration_s"] < 0:
            raise CmrtError("push_duration_s must be >= 0")

    # --- model -------------------------------------------------------------------
    def model(self):
        """The character plus this task's prop (compiled once per distinct prop parameters)."""
        return build_model(self.prop, model_values(self.prop, self.params))

    @property
    def has_goal(self) -> bool:
        """Whether a prop judges the task (catch, topple, strike) besides the pose change."""
        return self.prop is not None

    # --- motion -----------------------------------------------------------------
    def start_qpos(self) -> np.ndarray:
        """The start pose as humanoid qpos, feet flat and balanced over the support."""
        return _pose_qpos(tuple(sorted(self.start_pose_deg.items())), self.balance_joint)

    def end_qpos(self) -> np.ndarray:
        if self.end_pose_deg is None:
            return self.start_qpos()
        return _pose_qpos(tuple(sorted(self.end_pose_deg.items())), self.balance_joint)

    def via_qpos(self) -> np.ndarray:
        return _pose_qpos(tuple(sorted(self.via_pose_deg.items())), self.balance_joint)

    def keyframes(self) -> list[tuple[float, np.ndarray]]:
        """(fraction of T, qpos) of the poses the motion passes: start, [via], end."""
        return ref.keyframes(self)

    def reference(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Reference q, qd, qdd at times ``t_s`` (shape (n, nv)): see ``cmrt.reference.reference``."""
        return ref.reference(self, t_s)

    def joint_windows(self) -> dict[str, tuple[float, float]]:
        """Per-dof easing window as fractions of T (bare names expand to both sides)."""
        return ref.joint_windows(self)

    def push_at(self, t_s: float) -> float:
        """Horizontal push on the thorax at time t_s (N)."""
        start = self.params["push_start_s"]
        return self.params["push_force_n"] if start <= t_s < start + self.params["push_duration_s"] else 0.0

    def to_dict(self) -> dict:
        """The task as a task-file dict (``task_from_dict`` round-trips it): stored with runs."""
        out = {
            "name": self.name,
            "summary": self.summary,
            "params": dict(self.params),
            "param_ranges": {k: list(v) for k, v in self.param_ranges.items()},
            "start_pose_deg": dict(self.start_pose_deg),
            "balance_joint": self.balance_joint or "",
            "timing": {k: list(v) for k, v in self.timing.items()},
        }
        if self.end_pose_deg is not None:
            out["end_pose_deg"] = dict(self.end_pose_deg)
        if self.via_pose_deg is not None:
            out["via_pose_deg"] = dict(self.via_pose_deg)
        if self.prop:
            out["prop"] = {"kind": self.prop}
        if self.speed_param:
            out["speed_param"] = self.speed_param
        if self.robust != RobustSpec():
            out["robust"] = self.robust.to_table()
        return out

    def content_hash(self) -> str:
        """Hash of everything that changes the physics of a clip or its score (not name or summary; the
        ensemble only when robust scoring is on: a robust objective is another problem's)."""
        skip = ("name", "summary") if self.robust.enabled else ("name", "summary", "robust")
        body = {k: v for k, v in self.to_dict().items() if k not in skip}
        return hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()[:16]

    def task_window_s(self) -> tuple[float, float]:
        """[P, P + T]: where the motion happens (the whole clip for a task without one)."""
        if self.duration_s > 0:
            return self.preparation_s, self.preparation_s + self.duration_s
        return 0.0, self.clip_s

    def tracking_bound_rad(self, times_s: np.ndarray) -> float:
        """RMS joint error (actuated joints, at ``times_s``) of the reference against itself played
        ``max_tracking_lag`` x T late: the largest tracking error that still counts as the motion asked for."""
        dofs = list(character().actuated_dofs)
        lag = self.params["max_tracking_lag"] * self.duration_s
        q, q_late = self.reference(times_s)[0], self.reference(times_s - lag)[0]
        return float(np.sqrt(np.mean((q[:, dofs] - q_late[:, dofs]) ** 2))) if len(times_s) else 0.0

    def final_pose_error_rad(self, qpos: np.ndarray) -> float:
        """Euclidean distance of the actuated joint angles from the task's target pose."""
        dofs = list(character().actuated_dofs)
        return float(np.linalg.norm(qpos[dofs] - self.end_qpos()[dofs]))


def _angles(pose_deg: dict[str, float]) -> dict[str, float]:
    return joint_angles_from_pose({k: math.radians(v) for k, v in pose_deg.items()})


_QPOS_CACHE: dict = {}


def _pose_qpos(pose_items: tuple, balance_joint: str | None) -> np.ndarray:
    key = (pose_items, balance_joint)
    if key not in _QPOS_CACHE:
        _QPOS_CACHE[key] = feet_flat_qpos(_angles(dict(pose_items)), balance_joint)
    return _QPOS_CACHE[key].copy()


# --- loading --------------------------------------------------------------------
def available_tasks() -> list[str]:
    """Names of the tasks shipped with cmrt (``load_task(name)`` loads each)."""
    return sorted(f.name.removesuffix(".toml") for f in TASKS_DIR.iterdir() if f.name.endswith(".toml"))


def load_task(name_or_path: str) -> Task:
    """Load a shipped task by name (``bend``) or a user's task file by path (anything ending in ``.toml``)."""
    path = Path(name_or_path)
    if path.suffix != ".toml":
        if name_or_path not in available_tasks():
            raise CmrtError(f"unknown task '{name_or_path}' (known: {', '.join(available_tasks())})")
        path = TASKS_DIR / f"{name_or_path}.toml"
    try:
        raw = tomllib.loads(path.read_text())
    except OSError as exc:
        raise CmrtError(f"cannot read task file {path}: {exc.strerror}") from None
    except tomllib.TOMLDecodeError as exc:
        raise CmrtError(f"malformed task file {path}: {exc}") from None
    return task_from_dict(raw, source=str(path), default_name=path.stem)


def _bad_robust(source: str):
    raise CmrtError(f"{source}: [robust] must be a table")


def task_from_dict(raw: dict, source: str = "<dict>", default_name: str = "task") -> Task:
    """A task from a task-file dict (TOML, or a stored run's definition), validated; errors name ``source``."""
    allowed = {
        "name",
        "summary",
        "speed_param",
        "balance_joint",
        "params",
        "param_ranges",
        "start_pose_deg",
        "end_pose_deg",
        "via_pose_deg",
        "timing",
        "prop",
        "robust",
    }
    unknown = set(raw) - allowed
    if unknown:
        raise CmrtError(f"{source}: unknown key(s) {', '.join(sorted(unknown))}")
    params = dict(DEFAULT_PARAMS)
    prop = raw.get("prop", {}).get("kind") if isinstance(raw.get("prop"), dict) else None
    if "prop" in raw:
        if prop not in PROPS:
            raise CmrtError(f"{source}: prop.kind must be one of {', '.join(PROPS)}")
        params.update(PROPS[prop].PARAMS)
    for key, value in raw.get("params", {}).items():
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise CmrtError(f"{source}: parameter '{key}' must be a number")
        params[key] = float(value)
    ranges = {}
    for key, value in raw.get("param_ranges", {}).items():
        if key not in params or not (isinstance(value, list) and len(value) == 2):
            raise CmrtError(f"{source}: param_ranges.{key} must be [low, high] of a known parameter")
        ranges[key] = (float(value[0]), float(value[1]))
    speed_param = raw.get("speed_param")
    if speed_param is not None and speed_param not in params:
        raise CmrtError(f"{source}: speed_param '{speed_param}' is not a parameter")
    for table in ("start_pose_deg", "end_pose_deg", "via_pose_deg"):
        for key, value in raw.get(table, {}).items():
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise CmrtError(f"{source}: {table}.{key} must be a number of degrees")
    timing = {}
    for key, value in raw.get("timing", {}).items():
        ok = isinstance(value, list) and len(value) == 2 and all(isinstance(v, (int, float)) for v in value)
        if not ok or not 0.0 <= value[0] < value[1] <= 1.0:
            raise CmrtError(f"{source}: timing.{key} must be [start, end] fractions of T with 0 <= start < end <= 1")
        timing[key] = (float(value[0]), float(value[1]))
    task = Task(
        name=str(raw.get("name", default_name)),
        summary=str(raw.get("summary", "")),
        params=params,
        param_ranges=ranges,
        start_pose_deg={k: float(v) for k, v in raw.get("start_pose_deg", {}).items()},
        end_pose_deg={k: float(v) for k, v in raw["end_pose_deg"].items()} if "end_pose_deg" in raw else None,
        via_pose_deg={k: float(v) for k, v in raw["via_pose_deg"].items()} if "via_pose_deg" in raw else None,
        balance_joint=raw.get("balance_joint", "ankle") or None,
        timing=timing,
        prop=prop,
        speed_param=speed_param,
        source=source,
        robust=RobustSpec.from_table(raw.get("robust", {}), source) if isinstance(raw.get("robust", {}), dict)
        else _bad_robust(source),
    )
    task.validate()
    try:
        joint_angles_from_pose({k: 0.0 for k in timing})
    except CmrtError as exc:
        raise CmrtError(f"{source}: timing: {exc}") from None
    task.start_qpos()  # fail now on unknown joints or unbalanceable poses
    task.end_qpos()
    if task.via_pose_deg is not None:
        task.via_qpos()
    return task
