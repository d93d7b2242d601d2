"""Ensembles of perturbed clips: robust CMRTs and their validation.

A CMRT optimized on the nominal clip alone sits on the edge of what it was tuned for:
a small shove or a heavier ball than expected and it falls. With ``--robust`` (or
``[robust] enabled = true`` in a task file) every candidate is scored on an ensemble of
clips that differ from the nominal one in ways the character cannot know in advance,
all stepped in the candidate's lockstep batch:

* the nominal clip;
* thorax pushes of +-``push_force_n`` for ``push_duration_s``, starting at each of
  ``push_moments`` (fractions of the task window [P, P + T]);
* the prop's mass x (1 +- ``mass_fraction``) (ball, slab; the pad has none);
* the motion played ``timing_fraction`` faster and slower (duration T x (1 -+ f)).

The candidate's objective is the members' mean plus ``worst_weight`` x (worst - mean),
a documented step from the average towards the worst case; it is a success only if
every member is. Training members are a fixed grid, validation members (reported as
``robustness`` for every run, plain or robust) are drawn once from a seeded generator
with other push moments, masses and timings, so both are deterministic and resumable.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace

import numpy as np

from cmrt.errors import CmrtError

VALIDATION_MEMBERS = 20
MAX_PUSH_MOMENTS = 4  # each adds two members to every candidate's batch (memory: cmrt.inputs)
MAX_PUSH_FORCE_N = 1e4
VALIDATION_SEED = 20091  # fixed: every run of every task is validated on the same draws


@dataclass(frozen=True)
class Perturbation:
    """What one ensemble member changes in the nominal clip."""

    push_force_n: float = 0.0  # horizontal push on the thorax, +x forward, added to the task's own
    push_start_s: float = 0.0
    push_duration_s: float = 0.0
    prop_mass_scale: float = 1.0  # the prop's mass x this (no effect without a massive prop)
    time_scale: float = 1.0  # the motion's duration T x this

    def push_at(self, t_s: np.ndarray) -> np.ndarray:
        """The member's extra thorax push at times ``t_s`` (N)."""
        on = (t_s >= self.push_start_s) & (t_s < self.push_start_s + self.push_duration_s)
        return np.where(on, self.push_force_n, 0.0)

    def task_variant(self, task):
        """The task as this member plays it (only the motion's timing changes the task itself); not range-checked:
        a perturbation may step just outside a speed range."""
        if self.time_scale == 1.0:
            return task
        params = dict(task.params, duration_s=task.params["duration_s"] * self.time_scale)
        return replace(task, params=params)


NOMINAL = Perturbation()


def _finite_number(v: object) -> bool:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return False
    return math.isfinite(v) if isinstance(v, float) else abs(v) <= 10**15


@dataclass(frozen=True)
class RobustSpec:
    """The ``[robust]`` table of a task file (all optional); ``enabled`` turns robust scoring on."""

    enabled: bool = False
    push_force_n: float = 25.0
    push_duration_s: float = 0.1
    push_moments: tuple[float, ...] = (0.0, 1.0)  # push starts, as fractions of the task window [P, P + T]
    mass_fraction: float = 0.1
    timing_fraction: float = 0.05
    worst_weight: float = 0.5  # objective = mean + worst_weight * (worst - mean)

    def __post_init__(self) -> None:
        numbers = [self.push_force_n, self.push_duration_s, self.mass_fraction, self.timing_fraction,
                   self.worst_weight, *self.push_moments]
        if not all(_finite_number(v) for v in numbers):
            raise CmrtError("robust: every value must be a finite number")
        if not 0 <= self.push_force_n <= MAX_PUSH_FORCE_N or not 0 <= self.push_duration_s <= 60:
            raise CmrtError(f"robust: need 0 <= push_force_n <= {MAX_PUSH_FORCE_N:g} N and "
                            "0 <= push_duration_s <= 60 s")
        if len(self.push_moments) > MAX_PUSH_MOMENTS or not all(-1 <= m <= 2 for m in self.push_moments):
            raise CmrtError(f"robust: push_moments must be at most {MAX_PUSH_MOMENTS} fractions of the task window, "
                            "each in [-1, 2]")
        if not 0 <= self.mass_fraction < 1 or not 0 <= self.timing_fraction < 0.5:
            raise CmrtError("robust: need 0 <= mass_fraction < 1 and 0 <= timing_fraction < 0.5")
        if not 0 <= self.worst_weight <= 1:
            raise CmrtError("robust: worst_weight must be in [0, 1]")

    @classmethod
    def from_table(cls, table: dict, source: str = "<dict>") -> RobustSpec:
        """From a task file's ``[robust]`` table (validated; errors name ``source``)."""
        known = {f.name for f in fields(cls)}
        unknown = set(table) - known
        if unknown:
            raise CmrtError(f"{source}: unknown key(s) in [robust]: {', '.join(sorted(map(repr, unknown)))[:200]}")
        values = dict(table)
        if "enabled" in values and not isinstance(values["enabled"], bool):
            raise CmrtError(f"{source}: robust.enabled must be true or false")
        if "push_moments" in values:
            if not isinstance(values["push_moments"], list):
                raise CmrtError(f"{source}: robust.push_moments must be a list of fractions of the task window")
            values["push_moments"] = tuple(values["push_moments"])
        try:
            return cls(**values)
        except CmrtError as exc:
            raise CmrtError(f"{source}: {exc}") from None

    def to_table(self) -> dict:
        """As a ``[robust]`` table (``from_table`` round-trips it)."""
        out = asdict(self)
        out["push_moments"] = list(self.push_moments)
        return out


def _push_start(task, fraction: float) -> float:
    start, stop = task.task_window_s()
    return start + fraction * (stop - start)


def training_members(task, spec: RobustSpec, has_prop_mass: bool) -> list[Perturbation]:
    """The fixed training grid: nominal, +-push at each moment, prop mass +-, timing +-."""
    members = [NOMINAL]
    if spec.push_force_n > 0 and spec.push_duration_s > 0:
        for moment in spec.push_moments:
            for sign in (1.0, -1.0):
                members.append(Perturbation(push_force_n=sign * spec.push_force_n,
                                            push_start_s=_push_start(task, moment),
                                            push_duration_s=spec.push_duration_s))
    if has_prop_mass and spec.mass_fraction > 0:
        members += [Perturbation(prop_mass_scale=1 + s * spec.mass_fraction) for s in (1.0, -1.0)]
    if spec.timing_fraction > 0 and task.params["duration_s"] > 0:
        members += [Perturbation(time_scale=1 + s * spec.timing_fraction) for s in (1.0, -1.0)]
    return members


def validation_members(task, spec: RobustSpec, has_prop_mass: bool, n: int = VALIDATION_MEMBERS,
                       seed: int = VALIDATION_SEED) -> list[Perturbation]:
    """Seeded draws unlike the training grid: each member combines a push of the spec's size in a random
    direction at a random moment from 0.2 s before the task window to 0.3 s after it, a random prop mass and
    a random timing inside the spec's ranges."""
    rng = np.random.default_rng(seed)
    start, stop = task.task_window_s()
    latest = min(stop + 0.3, task.clip_s - spec.push_duration_s)
    members = []
    for _ in range(n):
        sign = 1.0 if rng.random() < 0.5 else -1.0
        t0 = float(rng.uniform(max(0.0, start - 0.2), max(latest, start)))
        mass = float(1 + rng.uniform(-1, 1) * spec.mass_fraction) if has_prop_mass else 1.0
        timing = float(1 + rng.uniform(-1, 1) * spec.timing_fraction) if task.params["duration_s"] > 0 else 1.0
        members.append(Perturbation(sign * spec.push_force_n, t0, spec.push_duration_s, mass, timing))
    return members


def combine(objectives: list[float], spec: RobustSpec) -> float:
    """The ensemble's objective: the mean, moved ``worst_weight`` of the way to the worst member."""
    values = np.asarray(objectives, dtype=float)
    mean, worst = float(values.mean()), float(values.max())
    return mean + spec.worst_weight * (worst - mean)
