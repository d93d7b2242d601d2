"""A 3D clip: the 3D body standing under ``cmrt.control.spatial``'s momentum controller, pushed or not.

MuJoCo steps the physics at the model's 2 ms; the controller plans every ``control_every`` steps (125 Hz, as the
planar clips) and its torques are held between. A push is a force on the thorax (``push_n``, world frame, N) for
``push_duration_s``. The executed CoP is the touch sensors' (every foot point's normal force at its place), the
planned one the controller's point forces'. The body has fallen when its CoM has come down ``FALL_DROP_M`` from
where it stood; the fall's direction is where its CoM went horizontally.

The verdict is the planar one's for a clip without a motion to perform (the same bounds, ``cmrt.sim.objective``):
``balance`` (no fall), ``settled`` (the CoM still at the end), ``plan`` (planned and executed CoP within 5 mm on
each axis outside the impact windows) and ``cop_margin`` (the executed CoP at least 1 mm inside the support
polygon - the convex hull of the touching points - in every sample judged).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.spatial import ConvexHull, QhullError

from cmrt.body.character import character, feet_flat_qpos, joint_angles_from_pose
from cmrt.control.controller import ControllerConfig
from cmrt.control.spatial import SpatialController
from cmrt.sim.objective import MAX_PLAN_COP_ERROR_M, MIN_COP_MARGIN_M, SETTLED_COM_SPEED_M_S

BODY = "humanoid3d"
FALL_DROP_M = 0.25  # the CoM this far below its standing height: fallen (crouching to grasp stays above it)
IMPACT_WINDOW_S = 0.1  # after a push starts, plan and execution may part (the planar verdict's impact window)
SETTLE_S = 0.1  # the first contacts settle from the initial pose: not judged


@dataclass(frozen=True)
class StandResult:
    """A 3D standing clip, sampled at every control step."""

    time_s: np.ndarray  # (n,)
    com_m: np.ndarray  # (n, 3)
    cop_xy_m: np.ndarray  # (n, 2) executed: the touch sensors' over the control step before the sample
    plan_cop_xy_m: np.ndarray  # (n, 2) planned for that control step: the controller's point forces'
    fell: bool
    fall_time_s: float | None
    fall_direction_xy: np.ndarray | None  # unit vector of the CoM's horizontal travel when it fell
    final_com_speed_m_s: float
    max_plan_cop_error_m: float  # |planned - executed| per axis, the larger, outside impact windows
    min_cop_margin_m: float  # the executed CoP's distance inside the support polygon, outside impact windows
    infeasible_steps: int  # control steps with no plan within the stops and motors' limits
    failed_rules: tuple[str, ...]  # of the verdict, in order; empty for a success

    @property
    def success(self) -> bool:
        """Stood (or was pushed and recovered), still at the end, the plan what happened, the CoP inside."""
        return not self.failed_rules


def stand_pose_qpos(pose_deg: dict[str, float] | None = None) -> np.ndarray:
    """The 3D body standing feet flat in a pose (degrees by joint name; default: the stand task's, every joint at
    zero)."""
    pose = pose_deg if pose_deg is not None else {}
    return feet_flat_qpos(joint_angles_from_pose({k: np.radians(v) for k, v in pose.items()}, BODY), body=BODY)


def stand_3d(clip_s: float = 3.0, push_n: tuple[float, float, float] = (0.0, 0.0, 0.0), push_start_s: float = 1.0,
             push_duration_s: float = 0.1, config: ControllerConfig = ControllerConfig()) -> StandResult:
    """Simulate the 3D body standing for ``clip_s``, pushed at the thorax by ``push_n``."""
    ch = character(BODY)
    m = ch.model
    d = mujoco.MjData(m)
    d.qpos[:] = stand_pose_qpos()
    mujoco.mj_forward(m, d)
    ctl = SpatialController(ch, d.qpos.copy(), config)
    points = list(ch.foot_point_geoms)
    push = np.asarray(push_n, float)
    start_z = float(d.subtree_com[1, 2])
    rows: list[tuple] = []
    infeasible = 0
    fall_time = None
    held_cop = np.full(2, np.nan)  # the CoP the torques held since the last control step were planned for
    for k in range(int(round(clip_s / m.opt.timestep))):
        t = k * m.opt.timestep
        if k % config.control_every == 0:
            touch = d.sensordata[:len(points)].copy()
            xy = d.geom_xpos[points, :2]
            cop = touch @ xy / touch.sum() if touch.sum() > 0 else np.full(2, np.nan)
            rows.append((t, d.subtree_com[1].copy(), cop, held_cop, _margin(cop, xy[touch > 0.0])))
            plan = ctl.plan(d, touch > 0.0)
            infeasible += ctl.infeasible
            d.ctrl[:] = plan.torque_nm
            held_cop = plan.cop_xy_m
            if fall_time is None and d.subtree_com[1, 2] < start_z - FALL_DROP_M:
                fall_time = t
        d.xfrc_applied[ch.thorax_body, :3] = push if push_start_s <= t < push_start_s + push_duration_s else 0.0
        mujoco.mj_step(m, d)
    time_s = np.array([r[0] for r in rows])
    com = np.array([r[1] for r in rows])
    cop, plan_cop = np.array([r[2] for r in rows]), np.array([r[3] for r in rows])
    margin = np.array([r[4] for r in rows])
    mujoco.mj_subtreeVel(m, d)
    return _result(time_s, com, (cop, plan_cop, margin), fall_time, push_start_s, infeasible,
                   float(np.linalg.norm(d.subtree_linvel[1])))


def _margin(cop: np.ndarray, touching_xy: np.ndarray) -> float:
    """How far ``cop`` is inside the convex hull of the touching points (m; negative outside, 0 on a line)."""
    if not np.isfinite(cop).all() or len(touching_xy) < 3:
        return 0.0
    try:
        hull = ConvexHull(touching_xy)
    except QhullError:  # the points on one line (a foot on its edge)
        return 0.0
    return float(-(hull.equations[:, :2] @ cop + hull.equations[:, 2]).max())


def _result(time_s: np.ndarray, com: np.ndarray, cops: tuple[np.ndarray, np.ndarray, np.ndarray],
            fall_time: float | None, push_start_s: float, infeasible: int, final_speed: float) -> StandResult:
    """The clip's figures and verdict from its samples (``cops``: executed, planned, the executed one's margin)."""
    cop, plan_cop, margin = cops
    judged = (time_s >= SETTLE_S) & ((time_s < push_start_s) | (time_s >= push_start_s + IMPACT_WINDOW_S))
    if fall_time is not None:
        judged &= time_s < fall_time
    gap = np.abs(plan_cop - cop)[judged]
    gap = gap[np.isfinite(gap).all(axis=1)]
    direction = None
    if fall_time is not None:
        travel = com[time_s <= fall_time][-1, :2] - com[0, :2]
        direction = travel / max(float(np.linalg.norm(travel)), 1e-12)
    max_gap = float(gap.max()) if gap.size else float("nan")
    min_margin = float(margin[judged].min()) if judged.any() else float("nan")
    failed = tuple(rule for rule, broken in (
        ("balance", fall_time is not None), ("settled", not final_speed < SETTLED_COM_SPEED_M_S),
        ("plan", not max_gap <= MAX_PLAN_COP_ERROR_M), ("cop_margin", not min_margin >= MIN_COP_MARGIN_M)) if broken)
    return StandResult(time_s, com, cop, plan_cop, fall_time is not None, fall_time, direction, final_speed,
                       max_gap, min_margin, infeasible, failed)
