"""The task record: reference motion, push, clip timing, objective settings.

A task is data, not code (its files are read by ``cmrt.motion.taskfile``). Every number lives in
``[params]`` so that ``--set KEY=VALUE`` can override any of them; poses are tables of joint angles in
degrees.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field, replace

import numpy as np

from cmrt import inputs
from cmrt.body.character import character, feet_flat_qpos, joint_angles_from_pose
from cmrt.body.props import BALL_RADIUS_M, build_model, model_values, prop_class
from cmrt.body.stance import feet_heel_x, stance_qpos
from cmrt.body.surface import BOX_PARAMS, SURFACE_PARAMS, Support
from cmrt.errors import CmrtError
from cmrt.inputs import MAX_RUN_S, Range, param_range, shown
from cmrt.modes import DEFAULT_REFERENCE_MODE, REFERENCE_MODES
from cmrt.motion import reference as ref
from cmrt.motion.ensemble import RobustSpec
from cmrt.motion.footsteps import PlannedStep, check_plan
from cmrt.motion.gait import Gait, check_gait, gait_motion
from cmrt.motion.reference import Schedule

MIN_TAIL_S = 0.5

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
    # stepping (cmrt.control.stepping, docs/stepping.md): 0 feet planted (the paper's setting), 1 the momentum
    # supervisor (Wu-Zordan eq. 5), 2 its capture-point variant
    "stepping": 0.0,
    "step_time_s": 0.4,  # lift-off to touchdown
    "step_height_m": 0.05,  # how high the swing foot's heel rises
    # a footstep plan (Task.steps): > 0, every planned step takes this long (s): a plan's speed, as duration_s is a
    # pose change's (its CMRTs interpolate across it); 0: each as the plan says
    "planned_step_s": 0.0,
    # the ground (cmrt.body.surface, docs/surfaces.md): friction, slope, a tilting or moving platform
    **SURFACE_PARAMS,
}
#: Parameters that change nothing while ``stepping`` is 0: left out of the content hash then, so the hashes
#: of planted-feet tasks (and the stored runs keyed by them) are those of before stepping existed.
STEPPING_PARAMS = ("stepping", "step_time_s", "step_height_m")


#: Parameters added after runs and library entries were stored, with the value everything before them had: at it,
#: they are left out of what hashes and matches compare.
LATER_PARAMS = {"planned_step_s": 0.0, "ball_radius_m": BALL_RADIUS_M}


def active_params(params: dict, planned: bool = False) -> dict:
    """``params`` without those that change nothing - the stepping ones while ``stepping`` is 0 (or absent, as
    in runs and library entries made before stepping existed) and no footstep plan is ``planned``, and the
    surface's at the still level floor's values, and those added later at the value everything before them had
    (``LATER_PARAMS``): what hashes and matches compare (so tasks, runs and library entries of before keep theirs)."""
    out = {k: v for k, v in params.items() if not (k in SURFACE_PARAMS and v == SURFACE_PARAMS[k])
           and not (k in LATER_PARAMS and v == LATER_PARAMS[k])}
    if params.get("stepping") or planned:  # a plan is carried out by the stepping supervisor
        return out
    return {k: v for k, v in out.items() if k not in STEPPING_PARAMS}


#: What a 3D task may set for now (docs/body3d.md): it stands, pushed at the thorax forward and sideways, or
#: lifts a foot (``stance_side`` +-1) over T = ``duration_s`` from P = ``preparation_s``.
PARAMS_3D = frozenset({"clip_s", "push_force_n", "push_force_y_n", "push_start_s", "push_duration_s", "preparation_s",
                       "duration_s", "stance_side", "lift_fraction", "stop_threshold", "max_tracking_lag"})
#: The 3D parameters a planar task does not have, with their defaults (a 3D task always has them).
DEFAULTS_3D = {"push_force_y_n": 0.0, "stance_side": 0.0, "lift_fraction": 0.35}
MIN_HOLD_3D_S = 0.5  # s: a leg lift's clip holds the one-leg pose at least this long after T


#: The props a 3D pose change may hold, push or strike (``cmrt.body.props``; docs/body3d.md, *The catch in 3D*,
#: *The push in 3D*, *The punch in 3D*).
PROPS_3D = ("ball", "slab", "bag")


def params_off_3d(params: dict[str, float], prop: str | None = None) -> list[str]:
    """The parameters a 3D task sets that the 3D body does not take yet (``PARAMS_3D`` and its prop's aside, any
    off its default): a task file's and a ``--set``'s check, one rule."""
    own = PARAMS_3D | {"via_fraction"} | set(prop_class(prop).PARAMS if prop in PROPS_3D else ())
    return sorted(k for k, v in params.items() if k not in own and v != DEFAULT_PARAMS.get(k))


def check_motion_3d(params: dict[str, float], pose_change: bool) -> None:
    """A 3D task's motion: a leg lift (``stance_side`` +-1) has a T and holds the one-leg pose at least
    ``MIN_HOLD_3D_S`` after it; a pose change (``pose_change``: an end pose) keeps both feet down; standing has
    no T."""
    side, t_s = params["stance_side"], params["duration_s"]
    if side not in (-1.0, 0.0, 1.0):
        raise CmrtError(f"stance_side must be -1 (the right foot), 0 (both) or 1 (the left), got {side:g}")
    if pose_change and side != 0:
        raise CmrtError("a 3D task changes its pose or lifts a foot, not both (stance_side 0 with an end pose)")
    if side == 0 and t_s > 0 and not pose_change:
        raise CmrtError(f"duration_s = {t_s:g}: a 3D task moves to lift a foot (stance_side +1 or -1) or to an end "
                        "pose")
    if side != 0 and not (t_s > 0 and params["preparation_s"] + t_s + MIN_HOLD_3D_S <= params["clip_s"]):
        raise CmrtError(f"a leg lift needs duration_s > 0 and preparation_s + duration_s + {MIN_HOLD_3D_S:g} s <= "
                        f"clip_s, got {params['preparation_s']:g} + {t_s:g} and {params['clip_s']:g}")


#: Further thorax pushes a task file may declare, each as ``<prefix>_force_n``, ``_start_s``, ``_duration_s``.
EXTRA_PUSHES = ("push2", "push3")


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
    # where the controller's reference CoM and CoP come from (cmrt.control.references): "center" (the support
    # centre, Macchietto; ABC) or "yu" (GRF-weighted feet and Winter's CoP, Yu eq. 3.2-3.4)
    reference_mode: str = DEFAULT_REFERENCE_MODE
    # the footsteps asked for (cmrt.motion.footsteps; Wu-Zordan's directed steps): empty, the feet stay planted
    # unless ``stepping`` lets the supervisor step on its own
    steps: tuple[PlannedStep, ...] = ()
    # the body that does it (cmrt.body.character.BODIES): "planar", the paper's, or "humanoid3d" (docs/body3d.md:
    # standing and pushed, simulated by `cmrt simulate` alone for now)
    body: str = "planar"
    # the horizontal axes its CMRT acts in (docs/body3d.md, *CMRTs in x and y*): 1, the task's own (forward for a
    # pose change, sideways for a leg lift), or 2 on the 3D body - that and across it, at shared knot times
    cmrt_axes: int = 1

    @property
    def n_cmrt_params(self) -> int:
        """The optimizer's parameters of this task's CMRT (``cmrt.motion.curve.n_params``): 8, or 12 in two
        axes."""
        return 8 if self.cmrt_axes == 1 else 12

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
    def stepping(self) -> int:
        """0: feet planted; 1: the momentum supervisor steps; 2: the capture-point supervisor does."""
        return int(self.params["stepping"])

    @property
    def step_time_s(self) -> float:
        """A step's duration, lift-off to touchdown (s; used when stepping)."""
        return self.params["step_time_s"]

    @property
    def step_height_m(self) -> float:
        """How high the swing foot's heel rises mid-step (m; used when stepping)."""
        return self.params["step_height_m"]

    @property
    def planned_step_s(self) -> float:
        """Every planned step's duration (s; 0: each as its plan says)."""
        return self.params["planned_step_s"]

    @property
    def plan(self) -> tuple[PlannedStep, ...]:
        """The footsteps as carried out: ``steps`` with every duration ``planned_step_s`` when that is > 0."""
        if self.planned_step_s <= 0.0:
            return self.steps
        return tuple(replace(step, duration_s=self.planned_step_s) for step in self.steps)

    @property
    def gait(self) -> Gait | None:
        """The keyed gait the task tracks (``gait_*`` parameters, ``cmrt.motion.gait``; Yu's walking), or None."""
        return Gait.from_params(self.params)

    @property
    def feet_move(self) -> bool:
        """Whether the feet may leave their places: a footstep plan, a keyed gait or a stepping supervisor."""
        return bool(self.steps) or self.stepping != 0 or self.gait is not None

    @property
    def footsteps_planned(self) -> int:
        """How many steps the task asks for: its plan's, or its gait's (the closing step included)."""
        gait = self.gait
        return len(self.steps) if gait is None else gait.n_steps

    @property
    def support(self) -> Support:
        """The ground it is done on (``cmrt.body.surface``): its surface parameters as one typed record."""
        return Support.from_params(self.params)

    @property
    def speed(self) -> float | None:
        """The value of the task's speed parameter (None if it has none)."""
        return self.params[self.speed_param] if self.speed_param else None

    @property
    def decay_s(self) -> float:
        """D = L - P - T: the clip after the motion (s)."""
        return self.clip_s - self.preparation_s - self.duration_s

    def with_params(self, **overrides: float | str) -> Task:
        """A copy with parameters overridden (numbers, or text parsed strictly), validated against names and
        ranges."""
        params = dict(self.params)
        for key, value in overrides.items():
            if key not in params:
                raise CmrtError(f"task {shown(self.name)} has no parameter {shown(key)} "
                                f"(has: {', '.join(sorted(params))})")
            params[key] = inputs.number(value, f"parameter {key}", self.limit(key))
        task = replace(self, params=params)
        task.validate()
        return task

    def limit(self, key: str) -> Range:
        """The documented range of parameter ``key`` (``cmrt.inputs.TASK_PARAMS``, or the prop's ``LIMITS``)."""
        return param_range(key, prop_class(self.prop).LIMITS)

    def with_robust(self, enabled: bool = True) -> Task:
        """A copy scored on its robust ensemble (``cmrt.motion.ensemble``), or on the nominal clip alone. A 3D clip
        has one push window, the ensemble members' (``cmrt.sim.clip3d.perturbed_3d``): a 3D task that pushes of its
        own is refused here, before anything is simulated or stored."""
        if enabled and self.body != "planar" and (self.params.get("push_force_n") or self.params.get("push_force_y_n")):
            raise CmrtError(f"--robust: a {self.body} task that pushes of its own has no robust ensemble (one push "
                            "window per 3D clip: the members')")
        return replace(self, robust=replace(self.robust, enabled=enabled))

    def with_reference(self, mode: str | None) -> Task:
        """A copy whose controller takes its reference CoM/CoP from ``mode`` (None: unchanged)."""
        if mode is None:
            return self
        task = replace(self, reference_mode=reference_mode(mode, "reference"))
        if task.body != "planar":
            task.validate()  # a 3D pose change takes the centre reference only
        return task

    def sagittal_twin(self) -> Task:
        """A 3D pose change as the planar task of the same poses and timing (``cmrt.body.sagittal``: the 3D body
        playing it has the planar body's centroidal dynamics, so its reference asks the same ground force and CoP);
        CmrtError for any other 3D task."""
        if self.body == "planar":
            return self
        if self.end_pose_deg is None:
            raise CmrtError(f"task {shown(self.name)}: cmrt check judges a pose change's reference; a {self.body} "
                            "standing task or leg lift has none it can check yet (docs/body3d.md)")
        params = {k: v for k, v in self.params.items() if k not in DEFAULTS_3D}
        return replace(self, body="planar", params=params)

    def with_steps(self, plan: tuple[PlannedStep, ...] | None) -> Task:
        """A copy that takes these footsteps (None: unchanged), checked against the clip."""
        if plan is None:
            return self
        task = replace(self, steps=tuple(plan))
        task.validate()
        return task

    def with_speed(self, speed: float | None) -> Task:
        """A copy at this speed (None: unchanged)."""
        if speed is None:
            return self
        if not self.speed_param:
            raise CmrtError(f"task '{self.name}' has no speed parameter")
        lo, hi = self.param_ranges.get(self.speed_param, (-math.inf, math.inf))
        if isinstance(speed, int | float) and math.isfinite(speed) and not lo <= speed <= hi:  # the task's own
            # range, the one message for a speed it cannot take (not the parameter's wider documented limit)
            raise CmrtError(f"{self.speed_param} = {speed:g} is outside task {shown(self.name)} range [{lo:g}, {hi:g}]")
        return self.with_params(**{self.speed_param: speed})

    def validate(self) -> None:
        """CmrtError if a parameter is not finite, outside its documented range (``limit``) or the task's own
        ``param_ranges``, or the timing is impossible."""
        p = self.params
        for key, value in p.items():
            inputs.number(value, f"parameter {key}", self.limit(key))
        for key, (lo, hi) in self.param_ranges.items():
            if not lo <= p[key] <= hi:
                raise CmrtError(f"{key} = {p[key]:g} is outside task {shown(self.name)} range [{lo:g}, {hi:g}]")
        if p["clip_s"] + p["tail_s"] > MAX_RUN_S:
            raise CmrtError(f"clip_s + tail_s = {p['clip_s'] + p['tail_s']:g} s is longer than the longest clip "
                            f"cmrt simulates ({MAX_RUN_S:g} s)")
        if p["clip_s"] <= 0 or p["preparation_s"] < 0 or p["duration_s"] < 0:
            raise CmrtError("clip_s must be > 0, preparation_s and duration_s >= 0")
        if self.decay_s < -1e-12:
            raise CmrtError(f"preparation_s + duration_s exceeds clip_s ({p['clip_s']:g} s)")
        if self.end_pose_deg is not None and p["duration_s"] <= 0:
            raise CmrtError("a pose-change task needs duration_s > 0")
        if self.body != "planar":
            off = params_off_3d(p, self.prop)
            if off:
                raise CmrtError(f"{', '.join(off)}: not for the {self.body} body yet (it takes "
                                f"{', '.join(sorted(PARAMS_3D))})")
            check_motion_3d(p, self.end_pose_deg is not None)
            if self.prop == "ball" and p.get("ball_balanced", 1.0):  # its mass moved into the forearms: untried
                raise CmrtError("ball_balanced = 1: on the 3D body a caught ball stays a load the plan carries "
                                "(ball_balanced = 0) for now")
            if self.end_pose_deg is not None and self.reference_mode != DEFAULT_REFERENCE_MODE:
                raise CmrtError(f"reference {self.reference_mode}: a 3D pose change takes the centre reference for "
                                "now (docs/body3d.md)")
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
        for prefix in EXTRA_PUSHES:
            keys = [f"{prefix}_{k}" for k in ("force_n", "start_s", "duration_s")]
            if any(k in p for k in keys) and not all(k in p for k in keys):
                raise CmrtError(f"a second push needs all of {', '.join(keys)}")
        _check_box(p, self.prop)
        prop_class(self.prop).check(p)
        if self.steps:
            check_plan(self.plan, p["clip_s"])
        elif p.get("planned_step_s", 0.0) > 0.0:
            raise CmrtError("planned_step_s sets the duration of a footstep plan's steps: give the task steps too "
                            "(--steps)")
        if p.get("gait_steps", 0.0) != round(p.get("gait_steps", 0.0)):
            raise CmrtError(f"gait_steps must be a whole number, got {p['gait_steps']:g}")
        gait = self.gait
        if gait is not None:
            if self.steps or self.end_pose_deg is not None or p["stepping"]:
                raise CmrtError("a gait (gait_steps > 0) is the whole motion: no footstep plan, end pose or stepping "
                                "with it")
            check_gait(gait, self.start_qpos(), p["clip_s"])
        if p["stepping"] not in (0, 1, 2):
            raise CmrtError("stepping must be 0 (feet planted), 1 (momentum supervisor) or 2 (capture point)")

    # --- model -------------------------------------------------------------------
    def model(self):
        """The character plus this task's prop (compiled once per distinct prop parameters)."""
        return build_model(self.prop, model_values(self.prop, self.params), self.body)

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

    def schedule(self) -> Schedule:
        """What the reference motion is made of: the poses as qpos and their timing (``cmrt.motion.reference``)."""
        end = None if self.end_pose_deg is None else self.end_qpos()
        via = None if self.via_pose_deg is None else self.via_qpos()
        return Schedule(key=self.content_hash(), start_qpos=self.start_qpos(), end_qpos=end, via_qpos=via,
                        via_fraction=None if via is None else self.params["via_fraction"], timing=dict(self.timing),
                        preparation_s=self.preparation_s, duration_s=self.duration_s)

    def keyframes(self) -> list[tuple[float, np.ndarray]]:
        """(fraction of T, qpos) of the poses the motion passes: start, [via], end."""
        return [(f, q.copy()) for f, q in ref.keyframes(self.schedule())]

    def reference(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Reference q, qd, qdd at times ``t_s`` (shape (n, nv)): see ``cmrt.motion.reference.reference``. On a
        tilted support the body stays upright in the world: the trunk's pitch less the tilt, the ankles more (the
        feet stay flat on it; ``cmrt.body.surface``)."""
        gait = self.gait
        if gait is not None:  # the keyed gait (16 ms for a clip's 4000 steps: not cached)
            motion = gait_motion(gait, character(), self.start_qpos(), t_s)
            q, qd, qdd = motion.q, motion.qd, motion.qdd
        else:
            q, qd, qdd = ref.reference(self.schedule(), t_s)
        theta = self.support.tilt(t_s)
        if not np.any(theta[0]) and not np.any(theta[1]):
            return q, qd, qdd
        ankles = list(character().ankle_dofs)
        out = []
        for arr, v in zip((q, qd, qdd), theta, strict=True):
            arr = np.array(arr, dtype=float)
            arr[..., 2] -= v
            arr[..., ankles] += np.asarray(v)[..., None]
            out.append(arr)
        return tuple(out)

    def joint_windows(self) -> dict[str, tuple[float, float]]:
        """Per-dof easing window as fractions of T (bare names expand to both sides)."""
        return ref.joint_windows(self.schedule())

    def push_at(self, t_s: float) -> float:
        """Horizontal push on the thorax at time t_s (N): the task's push plus, if its file declares them,
        a second and third (``push2_*``, ``push3_*``: several pushes in one clip)."""
        start = self.params["push_start_s"]
        force = self.params["push_force_n"] if start <= t_s < start + self.params["push_duration_s"] else 0.0
        for prefix in EXTRA_PUSHES:
            if f"{prefix}_force_n" in self.params:
                start = self.params[f"{prefix}_start_s"]
                if start <= t_s < start + self.params[f"{prefix}_duration_s"]:
                    force += self.params[f"{prefix}_force_n"]
        return force

    def pushes_n(self, t_s: np.ndarray) -> np.ndarray:
        """``push_at`` at every time of ``t_s`` at once (the same sums in the same order)."""
        t = np.asarray(t_s, dtype=float)
        start = self.params["push_start_s"]
        force = np.where((start <= t) & (t < start + self.params["push_duration_s"]), self.params["push_force_n"], 0.0)
        for prefix in EXTRA_PUSHES:
            if f"{prefix}_force_n" in self.params:
                start = self.params[f"{prefix}_start_s"]
                on = (start <= t) & (t < start + self.params[f"{prefix}_duration_s"])
                force = np.where(on, force + self.params[f"{prefix}_force_n"], force)
        return force

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
        if self.reference_mode != DEFAULT_REFERENCE_MODE:  # absent for the default: older hashes stay valid
            out["reference"] = self.reference_mode
        if self.steps:  # absent without a plan, likewise
            out["steps"] = [step.to_table() for step in self.steps]
        if self.body != "planar":  # absent for the planar body, likewise
            out["body"] = self.body
        if self.cmrt_axes != 1:  # absent for one axis, likewise
            out["cmrt_axes"] = self.cmrt_axes
        return out

    def content_hash(self) -> str:
        """Hash of everything that changes the physics of a clip or its score (not name or summary; the
        ensemble only when robust scoring is on: a robust objective is another problem's)."""
        skip = ("name", "summary") if self.robust.enabled else ("name", "summary", "robust")
        body = {k: v for k, v in self.to_dict().items() if k not in skip}
        body["params"] = active_params(body["params"], planned=bool(self.steps))
        return hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()[:16]

    def motion_hash(self) -> str:
        """Hash of the motion itself - its poses, their timing, the balance joint, the prop - without the
        parameters (speed, clip, ...), which a known CMRT's record compares on their own: a CMRT optimized for
        another motion under the same task name (a task file edited, a shipped task re-authored) is not this
        motion's, whatever its speed."""
        keep = ("start_pose_deg", "end_pose_deg", "via_pose_deg", "timing", "balance_joint", "prop")
        body = {k: v for k, v in self.to_dict().items() if k in keep}
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
        """Euclidean distance of the actuated joint angles from the task's target pose (on a slope: stood upright
        on it, as the reference is at the end). Where the feet may move, the target is that pose stood over the
        feet where they are (``cmrt.body.stance``): after a step the pose's own straight hips cannot be taken."""
        dofs = list(character().actuated_dofs)
        end = self.end_qpos()
        if self.feet_move:
            try:
                end = stance_qpos(end, feet_heel_x(qpos))
            except CmrtError:  # feet too far apart to stand over (a split fall): not back in any pose
                return float("inf")
        end[list(character().ankle_dofs)] += float(self.support.tilt(self.clip_s + self.tail_s)[0])
        return float(np.linalg.norm(qpos[dofs] - end[dofs]))


def _check_box(p: dict, prop: str | None) -> None:
    """The floating box carries the character alone, on still water: its motion is its own."""
    if p.get("box_mass_kg", 0.0) <= 0.0:
        changed = [k for k in BOX_PARAMS[1:] if p.get(k, SURFACE_PARAMS[k]) != SURFACE_PARAMS[k]]
        if changed:
            raise CmrtError(f"{changed[0]} describes the floating box: set box_mass_kg > 0 too")
        return
    moving = [k for k in ("slope_deg", "tilt_amplitude_deg", "sway_amplitude_m", "heave_amplitude_m")
              if p.get(k, 0.0) != 0.0]
    if moving:
        raise CmrtError(f"the floating box moves as the water and the character move it: {moving[0]} cannot be "
                        "set with box_mass_kg")
    if prop:
        raise CmrtError(f"the floating box carries the character alone: task with prop '{prop}' cannot stand on it")


def _angles(pose_deg: dict[str, float]) -> dict[str, float]:
    return joint_angles_from_pose({k: math.radians(v) for k, v in pose_deg.items()})


_QPOS_CACHE: dict = {}


def _pose_qpos(pose_items: tuple, balance_joint: str | None) -> np.ndarray:
    key = (pose_items, balance_joint)
    if key not in _QPOS_CACHE:
        _QPOS_CACHE[key] = feet_flat_qpos(_angles(dict(pose_items)), balance_joint)
    return _QPOS_CACHE[key].copy()


def reference_mode(value: object, where: str) -> str:
    """``value`` if it is one of ``REFERENCE_MODES``; CmrtError naming ``where`` otherwise."""
    if not isinstance(value, str) or value not in REFERENCE_MODES:
        raise CmrtError(f"{where} must be one of {', '.join(REFERENCE_MODES)}, got {shown(value)}")
    return value
