"""A 3D clip without a prop runs whole in compiled code (cmrt.sim.spatial_loop), MuJoCo's ``mj_step`` called from
numba (cmrt.sim.mjc): the same clip as the Python loop a prop needs, bit for bit - a leg lift with its foot in the
air, a pose change, a push that topples the body, a step with no plan - and MuJoCo's step from compiled code is the
binding's."""

import dataclasses
import functools

import mujoco
import numpy as np
import pytest
from numba import njit

from cmrt.body.character import character
from cmrt.control.controller import ControllerConfig
from cmrt.control.spatial import SpatialTargetTable
from cmrt.motion.curve import Cmrt
from cmrt.motion.library import library_curve
from cmrt.motion.taskfile import load_task
from cmrt.sim import mjc, spatial, spatial_loop
from cmrt.sim.clip3d import clip_3d
from cmrt.sim.spatial import BODY, control_times_s, replay_3d, stand_3d, stand_pose_qpos


def _assert_same(a: spatial.StandResult, b: spatial.StandResult) -> None:
    """Every field of two clips' results equal, bit for bit (NaN where NaN)."""
    for field in dataclasses.fields(a):
        x, y = getattr(a, field.name), getattr(b, field.name)
        if isinstance(x, np.ndarray):
            assert x.shape == y.shape and np.array_equal(x, y, equal_nan=True), field.name
        elif isinstance(x, float) and np.isnan(x):
            assert np.isnan(y), field.name
        elif field.name != "inputs":
            assert x == y, field.name


def _clip(case: str) -> spatial.StandResult:
    if case == "toppled":
        return stand_3d(clip_s=1.5, push_n=(0.0, 300.0, 0.0), push_start_s=0.5)
    task = load_task("leg-lift" if case == "leg lift" else "bend3d")
    return clip_3d(task, library_curve(task) if case == "leg lift" else Cmrt.zero(task.clip_s)).result


@pytest.mark.parametrize("case", ["leg lift", "bend", "toppled"])
def test_the_compiled_clip_is_the_python_loop(case, monkeypatch):
    compiled = _clip(case)
    monkeypatch.setattr(spatial, "stand_3d", functools.partial(spatial.stand_3d, compiled=False))
    python = _clip(case)
    _assert_same(compiled, python)
    assert compiled.fell == (case == "toppled")


def test_a_step_with_no_plan_in_compiled_code_is_a_fall():
    """A step whose torques come out NaN (here: its CoM target NaN from 0.5 s) has no plan: the compiled loop counts
    the body lost there, as the Python loop does - the motors off from then on - and the replay is the clip."""
    times = control_times_s(1.5, ControllerConfig().control_every)
    com = np.tile(spatial.feet_centre_xy(stand_pose_qpos()), (times.size, 1))
    com[times >= 0.5] = np.nan
    table = SpatialTargetTable(com_xy_m=com)
    r = stand_3d(clip_s=1.5, motion=table)
    assert r.fell and r.fall_time_s == times[times >= 0.5][0] and r.infeasible_steps == 1
    assert not r.ctrl_nm[r.time_s >= r.fall_time_s].any() and np.isnan(r.plan_cop_xy_m[r.time_s > r.fall_time_s]).all()
    _assert_same(r, stand_3d(clip_s=1.5, motion=table, compiled=False))
    replayed = np.full_like(r.com_m, np.nan)
    replay_3d(r, com_out=replayed)
    assert np.array_equal(replayed, r.com_m)


@njit(cache=True, nogil=True)
def _steps(step, model_address, data_address, n):  # pragma: no cover - compiled
    for _ in range(n):
        step(model_address, data_address)


def test_mujocos_step_from_compiled_code_is_the_bindings():
    m = character(BODY).model
    a, b = mujoco.MjData(m), mujoco.MjData(m)
    for d in (a, b):
        d.qpos[:] = stand_pose_qpos()
        d.ctrl[:] = np.random.default_rng(2).uniform(-0.3, 0.3, m.nu)
        mujoco.mj_forward(m, d)
    for _ in range(300):
        mujoco.mj_step(m, a)
    _steps(mjc.c_functions().step, m._address, b._address, 300)
    assert b.time == a.time and np.array_equal(a.qpos, b.qpos) and np.array_equal(a.qvel, b.qvel)


def test_the_executed_cop_is_the_touch_sensors_weighted_mean():
    """Summed in the points' order (one arithmetic on every machine): numpy's weighted mean to rounding; NaN with
    no force on the floor."""
    rng = np.random.default_rng(4)
    for _ in range(200):
        touch = np.where(rng.random(8) < 0.7, rng.uniform(0.0, 300.0, 8), 0.0)
        xy = rng.uniform(-0.2, 0.2, (8, 2))
        cop = spatial_loop.executed_cop(touch, xy)
        if touch.sum() > 0.0:
            np.testing.assert_allclose(cop, touch @ xy / touch.sum(), rtol=1e-12, atol=1e-15)
        else:
            assert np.isnan(cop).all()


def test_a_clip_after_a_fall_is_the_clip_on_a_fresh_model():
    """Clips without a prop reuse one model and data per thread: after a clip that fell (its protective mode wrote
    the model's stiffness, damping and spring poses) the next is the clip a fresh copy of the model plays, and the
    body's own model is never written."""
    m = character(BODY).model
    names = ("jnt_stiffness", "dof_damping", "qpos_spring")
    before = [getattr(m, name).copy() for name in names]
    first = stand_3d(clip_s=1.0, push_n=(60.0, 0.0, 0.0), push_start_s=0.3)
    assert stand_3d(clip_s=1.5, push_n=(0.0, 300.0, 0.0), push_start_s=0.5).fell
    _assert_same(first, stand_3d(clip_s=1.0, push_n=(60.0, 0.0, 0.0), push_start_s=0.3))
    for name, values in zip(names, before, strict=True):
        assert np.array_equal(getattr(m, name), values)


def test_without_mujocos_c_library_a_clip_runs_its_python_loop(monkeypatch):
    """Where a build of mujoco keeps its C library elsewhere (``mjc.c_functions`` None), a clip and its replay run
    the Python loop: the same clip."""
    compiled = stand_3d(clip_s=1.5, push_n=(0.0, 300.0, 0.0), push_start_s=0.5)
    monkeypatch.setattr(mjc, "c_functions", lambda: None)
    python = stand_3d(clip_s=1.5, push_n=(0.0, 300.0, 0.0), push_start_s=0.5)
    _assert_same(compiled, python)
    replayed = np.full_like(python.com_m, np.nan)
    replay_3d(python, com_out=replayed)
    assert np.array_equal(replayed, python.com_m)


def test_a_toppling_clip_uses_a_sliver_of_the_arena():
    """A MuJoCo error inside compiled code ends the process (no Python exception through ctypes); the one a 3D clip
    could meet, its arena running out, is far off: a body toppling onto the floor uses under 1 % of it."""
    assert stand_3d(clip_s=3.0, push_n=(0.0, 400.0, 0.0), push_start_s=0.5).fell
    m, d = spatial._local.clip  # the thread's model and data the clip ran on
    assert 0 < d.maxuse_arena < 0.01 * m.narena


def test_the_compiled_planted_slide_is_numpys():
    """``spatial_loop.planted_slide`` is the numpy it replaced, bit for bit, on random runs of planted samples."""
    def numpy_slide(planted_xy: np.ndarray) -> float:  # cmrt.sim.spatial._planted_slide_m before it was compiled
        planted = ~np.isnan(planted_xy).any(axis=2)
        index = np.arange(len(planted_xy))[:, None]
        starts = planted & ~np.vstack([np.zeros((1, planted.shape[1]), bool), planted[:-1]])
        first = np.maximum.accumulate(np.where(starts, index, 0), axis=0)
        moved = planted_xy - np.take_along_axis(planted_xy, first[:, :, None], axis=0)
        dist = np.sqrt((moved ** 2).sum(axis=2))
        return float(dist[planted].max()) if planted.any() else 0.0

    rng = np.random.default_rng(8)
    for share in (0.0, 0.3, 0.9, 1.0):
        for _ in range(50):
            xy = rng.uniform(-0.2, 0.2, (int(rng.integers(1, 60)), 8, 2))
            xy[rng.random(xy.shape[:2]) >= share] = np.nan
            assert spatial_loop.planted_slide(xy) == numpy_slide(xy)
