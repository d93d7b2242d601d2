from pathlib import Path

import numpy as np
import pytest

from cmrt.body.character import character
from cmrt.body.surface import SURFACE_PARAMS
from cmrt.errors import CmrtError
from cmrt.motion.task import DEFAULT_PARAMS, Task
from cmrt.motion.taskfile import available_tasks, load_task, task_from_dict

V03_BEND = Path(__file__).parent.parent / "data" / "v03_bend.toml"  # the bend shipped until v0.3


def test_shipped_tasks_load():
    assert {"stand", "bend"} <= set(available_tasks())
    bend = load_task("bend")
    assert bend.speed == 0.4 and bend.clip_s == 2.6 and bend.preparation_s == 1.0
    assert bend.with_speed(1.2).decay_s == pytest.approx(0.4)  # ABC Table 1, slow bend


def test_common_parameters_are_typed_properties():
    """Every task's parameters are explicit read-only properties; any other is read from ``params``."""
    catch = load_task("catch").with_params(duration_s=0.5)
    for key in SURFACE_PARAMS:  # the ground's, as one typed record
        assert getattr(catch.support, key) == catch.params[key]
    for key in set(DEFAULT_PARAMS) - set(SURFACE_PARAMS):
        assert isinstance(getattr(Task, key), property) and getattr(Task, key).__doc__
        assert getattr(catch, key) == catch.params[key]
    assert catch.duration_s == 0.5
    assert not hasattr(Task, "__getattr__")
    with pytest.raises(AttributeError):
        catch.ball_mass_kg  # noqa: B018 - a prop's parameter: catch.params["ball_mass_kg"]
    with pytest.raises(AttributeError):
        catch.clip_s = 1.0


def test_reference_eases_between_poses():
    bend = load_task(str(V03_BEND)).with_speed(0.4)  # its joints have windows of their own ([timing])
    t = np.array([0.0, 0.99, 1.0, 1.2, 1.4, 2.0])
    q, qd, qdd = bend.reference(t)
    np.testing.assert_allclose(q[0], bend.start_qpos())
    np.testing.assert_allclose(q[-1], bend.end_qpos())
    # each joint is half-way at the middle of its own easing window ([timing], fractions of T)
    start, end = bend.start_qpos(), bend.end_qpos()
    for name, (a, b) in {"lumbar_dof": (0.0, 0.6), "knee_r": (0.4, 1.0)}.items():
        i = character().dof("lumbar" if name == "lumbar_dof" else name)
        mid = bend.preparation_s + 0.5 * (a + b) * bend.duration_s
        np.testing.assert_allclose(bend.reference(np.array([mid]))[0][0, i], 0.5 * (start[i] + end[i]))
    np.testing.assert_allclose(qd[[0, 1, 2, 4, 5]], 0.0, atol=1e-9)  # at rest outside [P, P + T]
    np.testing.assert_allclose(qdd[[0, 2, 4, 5]], 0.0, atol=1e-6)
    # qd is the derivative of q
    tt = np.linspace(1.05, 1.35, 7)
    fd = (bend.reference(tt + 1e-6)[0] - bend.reference(tt - 1e-6)[0]) / 2e-6
    np.testing.assert_allclose(bend.reference(tt)[1][:, 2:], fd[:, 2:], atol=1e-5)  # root x, z untracked


def test_overrides_are_validated():
    bend = load_task("bend")
    assert bend.with_params(duration_s="0.8").duration_s == 0.8
    with pytest.raises(CmrtError, match="no parameter"):
        bend.with_params(nope=1)
    with pytest.raises(CmrtError, match="number"):
        bend.with_params(duration_s="fast")
    with pytest.raises(CmrtError, match="range"):
        bend.with_speed(5.0)
    with pytest.raises(CmrtError, match="no speed"):
        load_task("stand").with_speed(0.4)


def test_bad_task_definitions():
    with pytest.raises(CmrtError, match="unknown task"):
        load_task("no-such-task")
    with pytest.raises(CmrtError, match="unknown joint"):
        task_from_dict({"params": {"duration_s": 1.0}, "end_pose_deg": {"tail": 3}})
    with pytest.raises(CmrtError, match="unknown key"):
        task_from_dict({"parms": {}})
    with pytest.raises(CmrtError, match="exceeds"):
        task_from_dict(
            {"params": {"clip_s": 1.0, "preparation_s": 1.0, "duration_s": 0.5}, "end_pose_deg": {"hip": -10}}
        )


def test_malformed_toml(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("name = \n")
    with pytest.raises(CmrtError, match="malformed"):
        load_task(str(bad))
