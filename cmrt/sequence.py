"""Sequences of pose changes with superposed CMRTs (ABC 4.2, Fig. 6).

A sequence file (shipped: ``cmrt/tasks/sequences/*.toml``; a user's: any path) lists motions - pose-change tasks with a
speed and a start time - that chain (each ends in the pose the next starts from). The
sequence is simulated as one clip: the reference follows each motion in turn, and the
CMRT is the sum of the motions' CMRTs, each shifted so that its own task starts at the
motion's start time: d(t) = sum_i d_i(t - start_i + P_i), where overlapping
displacements add (the paper's superposition). A motion's CMRT is the library's at its
speed, else one interpolated from the library's neighbouring speeds.

Format::

    name = "four-poses"
    summary = "..."
    tail_s = 1.2                 # standing after the last motion ends
    [[motion]]
    task = "bend"                # a pose-change task file
    speed = 0.5                  # its speed parameter
    start_s = 1.0                # when the pose change starts in the sequence
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cmrt.curve import Cmrt
from cmrt.errors import CmrtError
from cmrt.task import DEFAULT_PARAMS, TASKS_DIR, Task, load_task

SEQUENCES_DIR = TASKS_DIR / "sequences"


class SuperposedCmrt:
    """Sum of shifted CMRTs; quacks like :class:`Cmrt` for the simulator."""

    def __init__(self, clip_s: float, parts: list[tuple[float, Cmrt]]):
        self.clip_s = clip_s
        self.parts = parts  # (offset_s, curve): the curve's t = 0 is at offset_s in the sequence

    def displacement_m(self, t_s):
        """d(t): the sum of the shifted CMRTs (m)."""
        t = np.asarray(t_s, dtype=float)
        return sum((c.displacement_m(t - off) for off, c in self.parts), np.zeros_like(t))

    def velocity_m_s(self, t_s):
        t = np.asarray(t_s, dtype=float)
        return sum((c.velocity_m_s(t - off) for off, c in self.parts), np.zeros_like(t))

    def to_dict(self) -> dict:
        return {"clip_s": self.clip_s, "superposed": [{"offset_s": off, "cmrt": c.to_dict()} for off, c in self.parts]}


@dataclass(frozen=True)
class Motion:
    """One pose change of a sequence, starting its motion at ``start_s``."""

    task: Task  # with its speed set
    start_s: float

    @property
    def offset_s(self) -> float:
        """Where the motion's own clip (and CMRT) starts in the sequence."""
        return self.start_s - self.task.preparation_s


@dataclass(frozen=True)
class SequenceTask(Task):
    """A Task whose reference chains several pose changes (simulate/evaluate use it as is)."""

    motions: tuple[Motion, ...] = field(default_factory=tuple)

    def start_qpos(self) -> np.ndarray:
        """The first motion's start pose."""
        return self.motions[0].task.start_qpos()

    def end_qpos(self) -> np.ndarray:
        return self.motions[-1].task.end_qpos()

    def reference(self, t_s):
        """Each motion's reference from its start to the next one's: q, qd, qdd at ``t_s``."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        nv = self.start_qpos().size
        q, qd, qdd = np.zeros((t.size, nv)), np.zeros((t.size, nv)), np.zeros((t.size, nv))
        starts = [m.start_s for m in self.motions] + [np.inf]
        for i, m in enumerate(self.motions):
            mask = (t < starts[i + 1]) & ((t >= m.start_s) | (i == 0))
            if mask.any():
                q[mask], qd[mask], qdd[mask] = m.task.reference(t[mask] - m.offset_s)
        return q, qd, qdd


def load_sequence(name_or_path: str) -> SequenceTask:
    """A shipped sequence by name (``four-poses``) or a sequence file by path: checked to chain (each motion
    starts where the previous ended, after it ended)."""
    path = Path(name_or_path)
    if path.suffix != ".toml":
        path = SEQUENCES_DIR / f"{name_or_path}.toml"
    try:
        raw = tomllib.loads(path.read_text())
    except OSError as exc:
        known = ", ".join(sorted(f.name.removesuffix(".toml") for f in SEQUENCES_DIR.iterdir()
                                 if f.name.endswith(".toml")))
        raise CmrtError(f"cannot read sequence {name_or_path} ({exc.strerror}; known: {known})") from None
    except tomllib.TOMLDecodeError as exc:
        raise CmrtError(f"malformed sequence file {path}: {exc}") from None
    items = raw.get("motion")
    if not isinstance(items, list) or not items:
        raise CmrtError(f"{path}: a sequence needs [[motion]] entries")
    motions = []
    for item in items:
        try:
            task = load_task(str(item["task"])).with_speed(float(item["speed"]))
            motions.append(Motion(task, float(item["start_s"])))
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, CmrtError):
                raise
            raise CmrtError(f"{path}: each motion needs task, speed and start_s ({exc})") from None
    motions.sort(key=lambda m: m.start_s)
    for a, b in zip(motions, motions[1:], strict=False):
        if b.start_s < a.start_s + a.task.duration_s - 1e-9:
            raise CmrtError(f"{path}: motion '{b.task.name}' starts before '{a.task.name}' has ended")
        if np.max(np.abs(a.task.end_qpos()[2:] - b.task.start_qpos()[2:])) > 1e-6:
            raise CmrtError(f"{path}: '{b.task.name}' does not start from the pose '{a.task.name}' ends in")
    if any(m.task.prop for m in motions) or motions[0].offset_s < 0:
        raise CmrtError(f"{path}: motions must be pose changes starting at or after their preparation time")
    last = motions[-1]
    clip = max(max(m.offset_s + m.task.clip_s for m in motions), last.start_s + last.task.duration_s
               + float(raw.get("tail_s", 1.0)))
    params = dict(DEFAULT_PARAMS)
    params.update(clip_s=clip, preparation_s=motions[0].start_s,
                  duration_s=last.start_s + last.task.duration_s - motions[0].start_s,
                  cop_sample_step_s=float(raw.get("cop_sample_step_s", motions[0].task.cop_sample_step_s)))
    return SequenceTask(name=str(raw.get("name", path.stem)), summary=str(raw.get("summary", "")), params=params,
                        end_pose_deg=motions[-1].task.end_pose_deg, source=str(path), motions=tuple(motions))
