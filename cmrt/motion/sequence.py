"""Sequences of pose changes with superposed CMRTs (ABC 4.2, Fig. 6).

A sequence file (shipped: ``cmrt/motion/tasks/sequences/*.toml``; a user's: any path) lists motions -
pose-change tasks with a speed and a start time - that chain (each ends in the pose the next starts from). The
sequence is simulated as one clip: the reference follows each motion in turn, and the
CMRT is the sum of the motions' CMRTs, each shifted so that its own task starts at the
motion's start time: d(t) = sum_i d_i(t - start_i + P_i), where overlapping
displacements add (the paper's superposition). A motion's CMRT is the library's at its
speed, else one interpolated from the library's neighbouring speeds. The motions are one body's: the planar
body's, or the 3D body's pose changes (``four-poses-3d``: bend3d and rise3d; docs/body3d.md), whose clip is
``cmrt.sim.clip3d``'s.

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

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cmrt import inputs
from cmrt.errors import CmrtError
from cmrt.inputs import MAX_RUN_S, Range, shown
from cmrt.motion.curve import Cmrt
from cmrt.motion.task import DEFAULT_PARAMS, DEFAULTS_3D, Task
from cmrt.motion.taskfile import MAX_TEXT, TASKS_DIR, load_task

SEQUENCES_DIR = TASKS_DIR / "sequences"
SEQUENCE_KEYS = frozenset({"name", "summary", "tail_s", "cop_sample_step_s", "motion"})
MOTION_KEYS = frozenset({"task", "speed", "start_s"})
MAX_MOTIONS = 32
START_S = Range(0.0, MAX_RUN_S, unit="s")
TAIL_S = Range(0.0, MAX_RUN_S, unit="s")
COP_SAMPLE_STEP_S = Range(0.001, 1.0, unit="s")


class SuperposedCmrt:
    """Sum of shifted CMRTs; quacks like a one-axis :class:`Cmrt` for the simulators (the planar one and the 3D
    pose change's)."""

    axes = 1  # a sequence's motions are pose changes, their CMRTs forward
    cross_values_m = None

    def __init__(self, clip_s: float, parts: list[tuple[float, Cmrt]]):
        self.clip_s = clip_s
        self.parts = parts  # (offset_s, curve): the curve's t = 0 is at offset_s in the sequence

    def along(self) -> SuperposedCmrt:
        """Itself: the displacement along the motions' (forward) axis."""
        return self

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


def _known_sequences() -> str:
    return ", ".join(sorted(f.name.removesuffix(".toml") for f in SEQUENCES_DIR.iterdir() if f.name.endswith(".toml")))


def load_sequence(name_or_path: str) -> SequenceTask:
    """A shipped sequence by name (``four-poses``) or a sequence file by path (a regular UTF-8 file: see
    ``cmrt.inputs.read_text``): every field of the right type, numbers finite and in range, motions that chain
    (each starts where the previous ended, after it ended), the whole clip at most ``MAX_RUN_S``."""
    if not isinstance(name_or_path, str) or not name_or_path:
        raise CmrtError(f"a sequence is a shipped sequence's name or a .toml file, got {shown(name_or_path)}")
    path = Path(name_or_path)
    if path.suffix != ".toml":
        shipped = SEQUENCES_DIR / f"{name_or_path}.toml"
        if "/" in name_or_path or not shipped.is_file():
            raise CmrtError(f"unknown sequence {shown(name_or_path)} (known: {_known_sequences()})")
        path = Path(str(shipped))
    where = f"sequence file {shown(str(path), 120)}"
    raw = inputs.load_toml(path, "sequence file")
    unknown = set(raw) - SEQUENCE_KEYS
    if unknown:
        raise CmrtError(f"{where}: unknown key(s) {', '.join(shown(k) for k in sorted(unknown))}")
    items = raw.get("motion")
    if not isinstance(items, list) or not items or len(items) > MAX_MOTIONS:
        raise CmrtError(f"{where}: a sequence needs 1 to {MAX_MOTIONS} [[motion]] entries")
    for key in ("name", "summary"):
        if not isinstance(raw.get(key, ""), str) or len(raw.get(key, "")) > MAX_TEXT:
            raise CmrtError(f"{where}: {key} must be a string, got {shown(raw.get(key))}")
    motions = []
    for i, item in enumerate(items, 1):
        at = f"{where}: motion {i}"
        if not isinstance(item, dict) or set(item) != MOTION_KEYS:
            raise CmrtError(f"{at} needs exactly task, speed and start_s, got {shown(item)}")
        if not isinstance(item["task"], str):
            raise CmrtError(f"{at}: task must be a task's name or a .toml file, got {shown(item['task'])}")
        speed = inputs.number(item["speed"], f"{at}: speed", text=False)
        start_s = inputs.number(item["start_s"], f"{at}: start_s", START_S, text=False)
        try:
            task = load_task(item["task"]).with_speed(speed)
        except CmrtError as exc:
            raise CmrtError(f"{at}: {exc}") from None
        if motions and task.body != motions[0].task.body:  # one clip, one body
            raise CmrtError(f"{at}: task {shown(task.name)} is done with the {task.body} body, the sequence's "
                            f"first motion with the {motions[0].task.body} body: a sequence has one body")
        if task.cmrt_axes != 1:
            raise CmrtError(f"{at}: task {shown(task.name)}'s CMRT is in two axes; superposed CMRTs are forward")
        motions.append(Motion(task, start_s))
    tail_s = inputs.number(raw.get("tail_s", 1.0), f"{where}: tail_s", TAIL_S, text=False)
    motions.sort(key=lambda m: m.start_s)
    for a, b in zip(motions, motions[1:], strict=False):
        if b.start_s < a.start_s + a.task.duration_s - 1e-9:
            raise CmrtError(f"{where}: motion '{b.task.name}' starts before '{a.task.name}' has ended")
        if np.max(np.abs(a.task.end_qpos()[2:] - b.task.start_qpos()[2:])) > 1e-6:
            raise CmrtError(f"{where}: '{b.task.name}' does not start from the pose '{a.task.name}' ends in")
    if any(m.task.prop for m in motions) or motions[0].offset_s < 0:
        raise CmrtError(f"{where}: motions must be pose changes starting at or after their preparation time")
    last = motions[-1]
    clip = max(max(m.offset_s + m.task.clip_s for m in motions), last.start_s + last.task.duration_s + tail_s)
    step = inputs.number(raw.get("cop_sample_step_s", motions[0].task.cop_sample_step_s),
                         f"{where}: cop_sample_step_s", COP_SAMPLE_STEP_S, text=False)
    params = dict(DEFAULT_PARAMS) | (DEFAULTS_3D if motions[0].task.body != "planar" else {})
    params.update(clip_s=clip, preparation_s=motions[0].start_s,
                  duration_s=last.start_s + last.task.duration_s - motions[0].start_s, cop_sample_step_s=step)
    if clip + params["tail_s"] > MAX_RUN_S:
        raise CmrtError(f"{where}: the sequence's clip ({clip:g} s, with its {params['tail_s']:g} s standing tail) "
                        f"is longer than the longest clip cmrt simulates ({MAX_RUN_S:g} s)")
    return SequenceTask(name=raw.get("name", path.stem), summary=raw.get("summary", ""), params=params,
                        start_pose_deg=motions[0].task.start_pose_deg, end_pose_deg=motions[-1].task.end_pose_deg,
                        source=str(path), motions=tuple(motions), body=motions[0].task.body)
