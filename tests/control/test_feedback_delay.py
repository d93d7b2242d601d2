"""The balance feedback's delay (``ControllerConfig.feedback_delay_s``, issue 25): what it acts on, that both
control-step paths apply it alike, and that it makes the controller less able to absorb a push."""


import numpy as np

from cmrt import Cmrt, load_task
from cmrt.control import ControllerConfig
from cmrt.control.references import Targets
from cmrt.sim import simulate as simulate_module  # noqa: E402
from cmrt.sim.objective import evaluate
from cmrt.sim.simulate import _delayed, simulate, simulate_batch

DELAYED = ControllerConfig(feedback_delay_s=0.1)
INSTANT = ControllerConfig(feedback_delay_s=0.0)


def test_the_feedback_sees_the_com_of_tau_ago():
    """c_r + (c(t) - c(t - tau)) in the kernel's k (c_r - c(t)) is k (c_r - c(t - tau)); the same for the velocity;
    the reference CoP is untouched, and before the first tau the first control step stands in."""
    rec_com = np.zeros((2, 100, 2))
    fb_vel = np.zeros((2, 100))
    rec_com[:, :, 0] = np.arange(100) * 0.01  # x = 0.01 k
    fb_vel[:] = np.arange(100) * 0.1
    t = Targets(np.array([0.5, 0.6]), np.array([0.0, 0.1]), np.array([0.06, 0.07]))
    ids = np.array([0, 1])
    out = _delayed(t, 50, 80, ids, rec_com[ids, 80, 0], fb_vel[ids, 80], rec_com, fb_vel)
    np.testing.assert_allclose(out.com_x_m - rec_com[ids, 80, 0], t.com_x_m - rec_com[ids, 30, 0])
    np.testing.assert_allclose(out.com_vel_x_m_s - fb_vel[ids, 80], t.com_vel_x_m_s - fb_vel[ids, 30])
    assert out.cop_x_m is t.cop_x_m
    early = _delayed(t, 50, 20, ids, rec_com[ids, 20, 0], fb_vel[ids, 20], rec_com, fb_vel)
    np.testing.assert_allclose(early.com_x_m, t.com_x_m + rec_com[ids, 20, 0] - rec_com[ids, 0, 0])
    assert _delayed(t, 0, 80, ids, rec_com[ids, 80, 0], fb_vel[ids, 80], rec_com, fb_vel) is t


def test_the_compiled_and_python_control_steps_delay_alike(monkeypatch):
    """Bit for bit, falls included, with the delay on (the compiled tick keeps its own history)."""
    task = load_task("bend").with_speed(0.4)
    rng = np.random.default_rng(3)
    curves = [None, Cmrt.from_params(rng.normal(0.0, 0.5, 8), task.clip_s),
              Cmrt(task.clip_s, (0.5, 1.0, 1.5, 2.0), (3.0, -3.0, 3.0, -3.0))]
    compiled = simulate_batch(task, curves, DELAYED, threads=1)
    monkeypatch.setattr(simulate_module, "COMPILED_TICK", False)
    python = simulate_batch(task, curves, DELAYED, threads=1)
    assert any(t.fell for t in compiled)
    for a, b in zip(compiled, python, strict=True):
        assert a.fell == b.fell and a.fall_time_s == b.fall_time_s
        assert np.array_equal(a.qpos, b.qpos, equal_nan=True) and np.array_equal(a.cop_x_m, b.cop_x_m, equal_nan=True)
    undelayed = simulate_batch(task, curves[:1], INSTANT, threads=1)[0]
    assert not np.array_equal(undelayed.qpos, python[0].qpos, equal_nan=True)  # the delay did something


def test_a_delayed_controller_absorbs_less_of_a_push():
    """A 180 N x 0.1 s thorax push: recovered with instant feedback, a fall with 0.1 s of delay (measured
    thresholds: 194 N and 162 N; docs/controller.md)."""
    task = load_task("stand").with_params(push_force_n=180.0, clip_s=5.0)
    assert evaluate(task, simulate(task, config=INSTANT, record=False)).success
    delayed = evaluate(task, simulate(task, config=DELAYED, record=False))
    assert delayed.fell and delayed.fall_direction == "forward"
