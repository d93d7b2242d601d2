"""The compiled control step (cmrt.sim.tick) is the Python path's arithmetic: trajectories bit for bit."""

import dataclasses

import mujoco.batch
import numpy as np
import pytest

from cmrt import Cmrt, library_curve, load_task
from cmrt.body.props import prop_class
from cmrt.control import ControllerConfig
from cmrt.control.planar import PlanarKinematics
from cmrt.motion.ensemble import training_members
from cmrt.sim import simulate as simulate_module  # noqa: E402
from cmrt.sim.simulate import simulate_batch
from cmrt.sim.tick import linear_momentum


def _fields(trajectory) -> dict:
    return dict(trajectory.__dict__)


def _assert_identical(a, b):
    for name, x in _fields(a).items():
        y = _fields(b)[name]
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), name
        elif isinstance(x, dict):  # the prop's figures (NaN: not reached)
            assert x.keys() == y.keys() and np.array_equal(list(x.values()), list(y.values()), equal_nan=True), name
        else:
            assert x == y or (x != x and y != y), name


def test_linear_momentum_sums_the_bodies_as_numpy_does():
    """numpy sums a row's bodies pairwise (eight partial sums): the compiled sum must round the same way."""
    rng = np.random.default_rng(0)
    for nb in (1, 3, 7, 8, 9, 14, 17, 40):
        cinert = rng.normal(0.0, 1.0, (6, nb, 10)) * 10.0 ** rng.integers(-4, 4, (6, nb, 1))
        cvel = rng.normal(0.0, 3.0, (6, nb, 6))
        got = np.empty((6, 2))
        linear_momentum(np.arange(got.shape[0]), cinert, cvel, nb, got)
        assert np.array_equal(got, PlanarKinematics.linear_momentum(cinert, cvel))
        rows = np.array([1, 4])  # a subset of the batch's rows, read in place
        linear_momentum(rows, cinert, cvel, nb, got[:2])
        assert np.array_equal(got[:2], PlanarKinematics.linear_momentum(cinert[rows], cvel[rows]))


def _clips(task):
    rng = np.random.default_rng(1)
    curves = [Cmrt.from_params(rng.normal(0.0, s, 8), task.clip_s) for s in (0.0, 0.05, 0.6)]
    return curves + [Cmrt(task.clip_s, (0.5, 1.0, 1.5, 2.0), (3.0, -3.0, 3.0, -3.0))]  # absurd: falls early


@pytest.mark.parametrize("name", ["bend", "punch", "catch", "push"])
def test_compiled_control_step_equals_the_python_path(name, monkeypatch):
    """Scoring runs (falls included, props leaning or carried) give the same trajectories, every array bit
    for bit, with the compiled control step and with the Python loop it stands for; and it is used."""
    task = load_task(name)
    task = task.with_speed(0.4) if name == "bend" else task
    curves = _clips(task)
    calls = []
    tick = simulate_module.control_tick
    monkeypatch.setattr(simulate_module, "control_tick", lambda *a: calls.append(1) or tick(*a))
    compiled = simulate_batch(task, curves)
    assert len(calls) > 100 and any(t.fell for t in compiled)
    used = len(calls)
    monkeypatch.setattr(simulate_module, "COMPILED_TICK", False)
    python = simulate_batch(task, curves)
    assert len(calls) == used
    for a, b in zip(compiled, python, strict=True):
        _assert_identical(a, b)


def test_compiled_control_step_plays_ensemble_timings_as_the_python_path(monkeypatch):
    """An ensemble's members play the motion at other speeds (a reference per timing variant)."""
    task = load_task("bend").with_speed(0.4).with_robust()
    members = training_members(task, task.robust, prop_class(task.prop).mass_body is not None)
    assert len({m.time_scale for m in members}) > 1
    curves = [Cmrt.from_params(np.zeros(8), task.clip_s)] * len(members)
    compiled = simulate_batch(task, curves, perturbations=members)
    monkeypatch.setattr(simulate_module, "COMPILED_TICK", False)
    for a, b in zip(compiled, simulate_batch(task, curves, perturbations=members), strict=True):
        _assert_identical(a, b)


@pytest.mark.parametrize("name", ["bend", "catch"])
def test_a_step_the_compiled_path_cannot_do_hands_the_clip_to_the_python_path(name, monkeypatch):
    """A singular plan (LinAlgError) mid-clip: the Python loop takes over from that step (it finds the row
    by row), with the ground forces of the steps before summed and the prop stepped once; the trajectories
    are unchanged."""
    task = load_task(name)
    task = task.with_speed(0.4) if name == "bend" else task
    curves = _clips(task)
    calls = []
    tick = simulate_module.control_tick

    def singular_at_the_100th(*a):
        calls.append(1)
        if len(calls) == 100:
            raise np.linalg.LinAlgError("singular")
        return tick(*a)

    reference = simulate_batch(task, curves, threads=1)
    monkeypatch.setattr(simulate_module, "control_tick", singular_at_the_100th)
    handed_over = simulate_batch(task, curves, threads=1)
    assert len(calls) == 100
    for a, b in zip(reference, handed_over, strict=True):
        _assert_identical(a, b)


def test_the_direct_step_is_taken_and_equals_batch_step(monkeypatch):
    """The scoring loop steps through MuJoCo's bound C++ ``step`` with ids validated once (``direct_step``):
    with the installed MuJoCo that path is taken (``Batch.step`` is not called), and every array is bit for
    bit what ``Batch.step`` gives - also after falls, when only some rows step."""
    task = load_task("bend").with_speed(0.4)
    curves = _clips(task)
    simulate_batch(task, curves[:1])  # the settled start pose, cached: its own steps are not counted
    calls = []
    step = mujoco.batch.Batch.step
    monkeypatch.setattr(mujoco.batch.Batch, "step", lambda self, *a, **k: calls.append(1) or step(self, *a, **k))
    direct = simulate_batch(task, curves, threads=1)
    assert calls == [] and any(t.fell for t in direct) and not all(t.fell for t in direct)
    monkeypatch.setattr(simulate_module, "DIRECT_STEP", False)
    public = simulate_batch(task, curves, threads=1)
    assert len(calls) > 1000
    for a, b in zip(direct, public, strict=True):
        _assert_identical(a, b)


def test_a_changed_inlined_module_drops_the_compiled_ticks_cache(tmp_path):
    """numba keys a cache by the function's own file: when kernel.py or balance.py change, the tick's cached
    machine code (which compiled them in) must go, or the compiled path runs the old controller."""
    from cmrt.sim.tick import drop_stale_cache

    here = tmp_path / "tick.py"
    here.write_text("")
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    stale = [cache / "tick.control_tick-130.py311.nbi", cache / "tick.control_tick-130.py311.1.nbc"]
    other = cache / "simulate.cpython-311.pyc"
    for f in [*stale, other]:
        f.write_text("x")
    assert drop_stale_cache(here)  # no stamp yet: built from unknown sources
    assert not any(f.exists() for f in stale) and other.exists()
    stale[0].write_text("x")
    assert not drop_stale_cache(here)  # same sources: the cache stays
    assert stale[0].exists()
    (cache / "tick.inlined.sha256").write_text("another kernel")
    assert drop_stale_cache(here) and not stale[0].exists()


# catch (props, the most rows) in the fast subset; the others in the full suite
@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n != "catch" else n
                                  for n in ("bend", "punch", "catch", "push")])
def test_the_warm_start_changes_no_plan_the_qp_solves(name):
    """ControllerConfig.warm_start (each QP starts from the active set its simulation's last control step
    ended on) saves KKT solves, not results: the zero and library CMRTs' clips, falls included, are the cold
    start's bit for bit, scored and recorded (docs/performance.md: they differ only where the active set does
    not settle within its passes, seen on the rise's fall)."""
    task = load_task(name)
    task = task.with_speed(0.4) if name == "bend" else task
    curves = [None, library_curve(task)]
    cold = dataclasses.replace(ControllerConfig(), warm_start=False)
    assert ControllerConfig().warm_start
    for record in (False, True):
        warm = simulate_batch(task, curves, ControllerConfig(), record=record)
        for a, b in zip(warm, simulate_batch(task, curves, cold, record=record), strict=True):
            _assert_identical(a, b)
