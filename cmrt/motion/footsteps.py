"""Footstep plans: the steps a user asks for (Wu and Zordan 2010: "we input a series of footsteps for the
character to follow"), as task input.

A plan is a sequence of steps, each: which foot, where its centre lands (m along x from the centre of the start
stance, + forward), how long the step takes (lift-off to touchdown) and, optionally, when it lifts off (s from
the start of the clip; without it, a step lifts off ``DOUBLE_SUPPORT_S`` after the one before touched down, the
first one at ``FIRST_STEP_S``). On the command line (``--steps``) a plan is

    R:+0.30:0.6,L:+0.60:0.6          foot : x_m : duration_s [: start_s], comma-separated

and in a task file a list of tables, ``steps = [{foot = "R", x_m = 0.30, duration_s = 0.6}, ...]``. The stepping
supervisor (``cmrt.control.stepping``) carries the steps out with the swing path and QP of its reactive steps
and a capture-point plan of the CoM and CoP, and steps on its own when a push is more than the plan can absorb.
A task's ``planned_step_s`` (> 0) gives every step that duration: a plan's speed (``Task.plan``).

``check_plan`` refuses, in one line each, a plan no leg can do: a step reaching farther from the stance foot than
the swing leg reaches (``MAX_FORWARD_M``, ``MAX_BACKWARD_M``; the reactive steps' limits), a step shorter than
``MIN_DURATION_S`` or longer than ``MAX_DURATION_S``, a start time before the previous step has landed (steps
overlap) or out of order, and a plan that ends after the clip.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from cmrt.errors import CmrtError
from cmrt.inputs import shown

FEET = {"R": 0, "L": 1}  # the supervisor's foot index: 0 right, 1 left
FIRST_STEP_S = 0.5  # a plan's first step lifts off after this much standing (unless it says when)
DOUBLE_SUPPORT_S = 0.15  # between one step's touchdown and the next lift-off (unless the next says when)
MIN_DURATION_S, MAX_DURATION_S = 0.3, 1.5  # a step's lift-off to touchdown
MAX_FORWARD_M = 0.45  # how far the swing foot's centre may land ahead of the stance foot's (StepConfig.max_step_m)
MAX_BACKWARD_M = 0.30  # ... and behind it (StepConfig.max_back_step_m)
MAX_STEPS = 40
SETTLE_AFTER_S = 0.5  # the clip must go on this long after the last touchdown: the body comes to rest


@dataclass(frozen=True)
class PlannedStep:
    """One step of a plan."""

    foot: int  # 0 right, 1 left
    x_m: float  # where the foot's centre lands, from the start stance's centre (+ forward)
    duration_s: float  # lift-off to touchdown
    start_s: float | None = None  # lift-off time (None: after the step before, ``DOUBLE_SUPPORT_S`` later)

    def to_text(self) -> str:
        text = f"{'RL'[self.foot]}:{self.x_m:+g}:{self.duration_s:g}"
        return text if self.start_s is None else f"{text}:{self.start_s:g}"

    def to_table(self) -> dict:
        out = {"foot": "RL"[self.foot], "x_m": self.x_m, "duration_s": self.duration_s}
        if self.start_s is not None:
            out["start_s"] = self.start_s
        return out


def _number(text: object, what: str) -> float:
    if isinstance(text, bool):
        raise CmrtError(f"{what} must be a number, got {shown(text)}")
    try:
        value = float(text)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise CmrtError(f"{what} must be a number, got {shown(text)}") from None
    if not math.isfinite(value):
        raise CmrtError(f"{what} must be finite, got {shown(text)}")
    return value


def _step(foot: object, x_m: object, duration_s: object, start_s: object, where: str) -> PlannedStep:
    if not isinstance(foot, str) or foot.upper() not in FEET:
        raise CmrtError(f"{where}: the foot must be R or L, got {shown(foot)}")
    return PlannedStep(FEET[foot.upper()], _number(x_m, f"{where}: x_m"), _number(duration_s, f"{where}: duration_s"),
                       None if start_s is None else _number(start_s, f"{where}: start_s"))


def parse_steps(text: str) -> tuple[PlannedStep, ...]:
    """``--steps`` text -> a plan (not yet checked against a task: ``check_plan``)."""
    if not isinstance(text, str) or not text.strip():
        raise CmrtError("--steps needs foot:x_m:duration_s[:start_s] steps, comma-separated "
                        "(e.g. R:+0.30:0.6,L:+0.60:0.6)")
    plan = []
    for i, item in enumerate(text.split(","), start=1):
        fields = item.strip().split(":")
        if len(fields) not in (3, 4):
            raise CmrtError(f"--steps: step {i} must be foot:x_m:duration_s[:start_s], got {shown(item.strip())}")
        plan.append(_step(fields[0].strip(), fields[1], fields[2], fields[3] if len(fields) == 4 else None,
                          f"--steps: step {i}"))
    return tuple(plan)


def steps_from_tables(value: object, where: str) -> tuple[PlannedStep, ...]:
    """A task file's ``steps`` (a list of tables with foot, x_m, duration_s and optionally start_s)."""
    if not isinstance(value, list):
        raise CmrtError(f"{where}: steps must be a list of tables, got {shown(value)}")
    plan = []
    for i, table in enumerate(value, start=1):
        if not isinstance(table, dict) or not {"foot", "x_m", "duration_s"} <= set(table) or (
                set(table) - {"foot", "x_m", "duration_s", "start_s"}):
            raise CmrtError(f"{where}: steps[{i}] must be a table of foot, x_m, duration_s and optionally "
                            f"start_s, got {shown(table)}")
        plan.append(_step(table["foot"], table["x_m"], table["duration_s"], table.get("start_s"),
                          f"{where}: steps[{i}]"))
    return tuple(plan)


def timeline(plan: tuple[PlannedStep, ...]) -> list[tuple[float, float]]:
    """(lift-off, touchdown) of every step as planned (s)."""
    out, end = [], FIRST_STEP_S - DOUBLE_SUPPORT_S
    for step in plan:
        start = end + DOUBLE_SUPPORT_S if step.start_s is None else step.start_s
        end = start + step.duration_s
        out.append((start, end))
    return out


def check_plan(plan: tuple[PlannedStep, ...], clip_s: float, stance_x_m: tuple[float, float] = (0.0, 0.0)) -> None:
    """CmrtError (one line) for a plan the character cannot carry out as written. ``stance_x_m``: where the right
    and left foot's centres start, from the start stance's centre."""
    if len(plan) > MAX_STEPS:
        raise CmrtError(f"a plan has at most {MAX_STEPS} steps, got {len(plan)}")
    feet = list(stance_x_m)
    previous_end = -math.inf
    for i, (step, (start, end)) in enumerate(zip(plan, timeline(plan), strict=True), start=1):
        name = f"step {i} ({step.to_text()})"
        if not MIN_DURATION_S <= step.duration_s <= MAX_DURATION_S:
            raise CmrtError(f"{name}: a step takes {MIN_DURATION_S:g}-{MAX_DURATION_S:g} s, got {step.duration_s:g}")
        if start < 0.0:
            raise CmrtError(f"{name}: starts before the clip (start_s {start:g})")
        if start < previous_end + 1e-9:
            raise CmrtError(f"{name}: lifts off at {start:g} s, before step {i - 1} lands at {previous_end:g} s "
                            "(steps overlap, or are out of order)")
        reach = step.x_m - feet[1 - step.foot]  # from the stance foot's centre
        if reach > MAX_FORWARD_M + 1e-9 or reach < -MAX_BACKWARD_M - 1e-9:
            raise CmrtError(f"{name}: lands {reach:+.2f} m from the stance foot; a leg reaches "
                            f"{MAX_FORWARD_M:g} m forward and {MAX_BACKWARD_M:g} m back")
        feet[step.foot] = step.x_m
        previous_end = end
    if plan and previous_end + SETTLE_AFTER_S > clip_s + 1e-9:
        raise CmrtError(f"the last step lands at {previous_end:g} s: clip_s must be at least "
                        f"{previous_end + SETTLE_AFTER_S:g} s (the body comes to rest after it)")


def plan_text(plan: tuple[PlannedStep, ...]) -> str:
    """The ``--steps`` text of a plan."""
    return ",".join(step.to_text() for step in plan)
