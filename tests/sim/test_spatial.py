"""The 3D body standing under the 3D momentum controller (cmrt.sim.spatial): still for 10 s, 100 N x 0.1 s pushes
from four directions taken, 300 N from the side a fall toward the push, the plan what happens - each judged by the
planar verdict's rules."""

from dataclasses import replace

import numpy as np
import pytest

from cmrt.sim.objective import SETTLED_COM_SPEED_M_S
from cmrt.sim.spatial import _margin, stand_3d, stand_pose_qpos

PLAN_GAP_M = 0.005  # planned vs executed CoP, each axis (the planar verdict's bound)


@pytest.mark.slow  # a 10 s clip
def test_stands_still_for_ten_seconds():
    r = stand_3d(clip_s=10.0)
    assert r.success, r.failed_rules
    assert not r.fell and r.infeasible_steps == 0
    assert np.abs(r.com_m[:, :2] - r.com_m[0, :2]).max() < 0.001
    assert r.max_plan_cop_error_m <= PLAN_GAP_M
    assert r.final_com_speed_m_s < SETTLED_COM_SPEED_M_S
    assert abs(r.peak_normal_force_bw - 1.0) < 0.01 and r.max_foot_slip_m < 1e-4  # the feet carry the weight


def test_a_pose_placed_just_on_the_floor_is_not_a_fall_before_its_contacts_settle():
    """A standing pose put exactly on the floor touches it with no force at first (this one: every touch sensor 0
    at t = 0); the fall monitor judges from 0.1 s on, as the verdict's other rules do (it was a fall at t = 0)."""
    start = stand_pose_qpos({"shoulder": -15.0, "elbow": -95.0})
    r = stand_3d(clip_s=1.0, start_qpos=start)
    assert not r.fell and r.success, r.failed_rules


@pytest.mark.parametrize("push_n", [(100.0, 0.0, 0.0), (-100.0, 0.0, 0.0), (0.0, 100.0, 0.0), (0.0, -100.0, 0.0)])
def test_takes_a_100_n_push_from_every_side(push_n):
    r = stand_3d(clip_s=4.0, push_n=push_n)
    assert r.success, r.failed_rules
    assert r.min_cop_margin_m > 0.01  # the feet kept flat: the CoP never near an edge
    assert r.peak_normal_force_bw < 1.1 and r.airborne_s == 0.0  # no hop, no stamp
    assert r.max_joint_speed_rad_s < 2.0 and r.max_foot_slip_m < 0.01
    moved = r.com_m[:, :2] - r.com_m[0, :2]
    direction = np.asarray(push_n[:2]) / 100.0
    assert (moved @ direction).max() > 0.01  # the push moved it ...
    assert np.abs(moved[-1]).max() < 0.005  # ... and it came back over its feet
    assert r.final_com_speed_m_s < SETTLED_COM_SPEED_M_S
    assert r.max_plan_cop_error_m <= PLAN_GAP_M


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_300_n_from_the_side_topples_it_toward_the_push(side):
    r = stand_3d(clip_s=4.0, push_n=(0.0, 300.0 * side, 0.0))
    assert r.fell and not r.success and r.failed_rules[0] == "balance"
    assert r.fall_time_s < 1.2  # the capture point leaves the support during the push (it starts at 1.0 s)
    assert r.fall_direction_xy[1] * side > 0.9  # it leaves within 25 deg of the push ...
    assert r.topple_direction_xy[1] * side > 0.7  # ... and the protective topple goes that way (within 45 deg)
    assert r.com_m[-1, 2] < 0.5  # on the floor by the clip's end


def test_same_clip_same_result():
    a = stand_3d(clip_s=1.5, push_n=(0.0, 100.0, 0.0), push_start_s=0.5)
    b = stand_3d(clip_s=1.5, push_n=(0.0, 100.0, 0.0), push_start_s=0.5)
    np.testing.assert_array_equal(a.com_m, b.com_m)
    np.testing.assert_array_equal(a.plan_cop_xy_m, b.plan_cop_xy_m)


def test_the_cop_margin_is_the_distance_inside_the_touching_points():
    square = np.array([[0.0, 0.0], [0.2, 0.0], [0.2, 0.1], [0.0, 0.1]])
    assert _margin(np.array([0.1, 0.05]), square) == pytest.approx(0.05)
    assert _margin(np.array([0.19, 0.05]), square) == pytest.approx(0.01)
    assert _margin(np.array([0.25, 0.05]), square) == pytest.approx(-0.05)
    assert _margin(np.array([0.1, 0.0]), square[:2]) == 0.0  # fewer than three points: no area
    line = np.array([[0.0, 0.0], [0.1, 0.0], [0.2, 0.0]])
    assert _margin(np.array([0.1, 0.0]), line) == 0.0  # three on one line: no area either
    assert _margin(np.array([np.nan, 0.05]), square) == 0.0  # no CoP (nothing on the floor): no margin


def test_the_cop_margin_is_qhulls_to_rounding():
    """``_margin`` finds the hull's edges itself (ten times quicker than qhull for eight points): the same
    distance as ``scipy.spatial.ConvexHull``'s equations on random point sets, repeated points included."""
    from scipy.spatial import ConvexHull

    rng = np.random.default_rng(7)
    for n in (3, 4, 5, 8):
        for _ in range(200):
            pts = rng.normal(scale=0.1, size=(n, 2))
            pts = np.vstack([pts, pts[:1]])  # a point twice, as two touching spheres can be
            cop = rng.normal(scale=0.1, size=2)
            hull = ConvexHull(pts)
            assert _margin(cop, pts) == pytest.approx(-(hull.equations[:, :2] @ cop + hull.equations[:, 2]).max(),
                                                      abs=1e-12)


def test_the_weight_shifts_over_the_stance_foot_before_the_other_lifts():
    """The anticipatory part of a leg lift: by lift-off the CoM is over the stance foot's sole (within its half
    width, 4 cm, of the sole's centre line): one-leg balance is possible the moment the other foot leaves."""
    from cmrt.body.one_leg import one_leg_poses
    from cmrt.sim.spatial import leg_lift_3d, stand_pose_qpos

    centre = one_leg_poses(stand_pose_qpos(), 1).stance_centre_xy_m
    r = leg_lift_3d(shift_s=2.3, clip_s=2.9, stance=1).result  # Yu's reference: the reference's own shift
    k = np.searchsorted(r.time_s, 2.8 - 1e-9) - 1  # the last sample before lift-off (0.5 + 2.3 s)
    assert abs(r.com_m[k, 1] - centre[1]) < 0.04 and not r.fell
    assert abs(r.com_m[0, 1] - centre[1]) > 0.08  # it started over the midline


def test_the_cop_error_objective_is_the_papers_2_norm_plus_a_fall_penalty():
    from cmrt.sim.spatial import cop_error_objective

    r = stand_3d(clip_s=0.5)
    ref = np.tile(r.cop_xy_m[10], (len(r.time_s), 1))
    value = cop_error_objective(r, ref)
    err = np.nan_to_num(r.cop_xy_m - ref, nan=0.3)
    assert value == pytest.approx(np.linalg.norm(err) * np.sqrt(0.008 / 0.01))
    fallen = stand_3d(clip_s=2.0, push_n=(0.0, 300.0, 0.0))
    zero = np.zeros((len(fallen.time_s), 2))
    norm = np.linalg.norm(np.nan_to_num(fallen.cop_xy_m, nan=0.3)) * np.sqrt(0.008 / 0.01)
    span_s = fallen.time_s[-1] + 0.008  # the planar fall penalty: 10, and up to 10 more the earlier the fall
    assert cop_error_objective(fallen, zero) == pytest.approx(norm + 10.0 + 10.0 * (span_s - fallen.fall_time_s)
                                                              / span_s)
    # a fall scores worse than any stand that is not a success (5-10 over the norm): even one at the clip's end
    late = replace(fallen, fall_time_s=float(fallen.time_s[-1]))
    standing = replace(fallen, fell=False, fall_time_s=None, failed_rules=("plan",), max_plan_cop_error_m=0.1)
    assert cop_error_objective(late, zero) > cop_error_objective(standing, zero) == pytest.approx(norm + 10.0)


def test_a_step_with_no_plan_at_all_is_a_fall_not_a_crash(monkeypatch):
    """Where the QP has no solution even without the motors' limits the controller raises; the clip then counts the
    body as lost - a fall at that step, played out in the protective mode and scored as one - rather than ending the
    search that asked for it. The replay of the clip (the bench's floor) is the clip."""
    from cmrt.control.spatial import SpatialController
    from cmrt.errors import CmrtError
    from cmrt.sim.spatial import replay_3d

    plan = SpatialController.plan

    def failing(self, d, *args, **kwargs):
        if d.time >= 0.5:
            raise CmrtError("the 3D balance QP has no solution (status -1)")
        return plan(self, d, *args, **kwargs)

    monkeypatch.setattr(SpatialController, "plan", failing)
    r = stand_3d(clip_s=1.5, compiled=False)  # the loop that calls ``plan`` (tests/sim/test_spatial_loop.py: the
    assert r.fell and r.fall_time_s == pytest.approx(0.5, abs=0.01) and r.infeasible_steps == 1  # compiled one)
    assert "balance" in r.failed_rules
    assert np.all(r.ctrl_nm[np.searchsorted(r.time_s, r.fall_time_s):] == 0.0)  # the motors off from the fall on
    com = np.full_like(r.com_m, np.nan)
    replay_3d(r, com_out=com)
    assert np.array_equal(com, r.com_m)


def test_a_samples_margin_planted_points_and_joint_speed_are_numpys():
    """The compiled sample (``spatial_loop.sample``) is the numpy expressions it replaced, bit for bit: the CoP's
    margin inside the touching points (``_margin``), each point's place where it carries 5 N or more (NaN
    elsewhere), the fastest actuated joint; and with fewer than three points touching or no CoP, a margin of 0."""
    from cmrt.sim.simulate import PLANTED_FORCE_N
    from cmrt.sim.spatial_loop import sample

    rng = np.random.default_rng(5)
    acts = np.arange(6, 31)
    for touching in (8, 5, 3, 2, 0):
        touch = np.zeros(8)
        touch[rng.permutation(8)[:touching]] = rng.uniform(0.5, 200.0, touching)
        xy = rng.uniform(-0.2, 0.2, (8, 2))
        qvel = rng.standard_normal(31)
        for cop in (rng.uniform(-0.1, 0.1, 2), np.full(2, np.nan)):
            margin, planted, speed = sample(cop, touch, xy, qvel, acts, PLANTED_FORCE_N)
            assert margin == _margin(cop, xy[touch > 0.0])
            np.testing.assert_array_equal(planted, np.where(touch >= PLANTED_FORCE_N, 1.0, np.nan)[:, None] * xy)
            assert speed == float(np.abs(qvel[acts]).max())


def test_the_compiled_fall_rules_are_numpys():
    """``spatial_loop.fall_rules`` is the numpy it replaced, bit for bit, on random states: the capture point from
    the CoM and its velocity, the touching soles' centre (a mean), a foot rolled past the limit, the capture
    point's margin outside the soles, the CoM's height; hands leaning on a prop suspend the capture rule."""
    from cmrt.body.character import GRAVITY_M_S2, character
    from cmrt.sim.balance import BalanceLimits
    from cmrt.sim.spatial import BODY, _feet
    from cmrt.sim.spatial_loop import fall_rules

    limits, ch = BalanceLimits(), character(BODY)
    feet, soles = _feet()
    vector = np.array([np.cos(limits.roll_rad), limits.capture_margin_m, limits.com_height_m, GRAVITY_M_S2])
    rng = np.random.default_rng(6)
    seen = set()
    for _ in range(400):
        com = np.array([*rng.uniform(-0.15, 0.15, 2), rng.uniform(0.5, 1.0)])
        vel = rng.normal(0.0, 0.4, 3)
        touch = np.where(rng.random(8) < 0.7, rng.uniform(0.0, 100.0, 8), 0.0)
        geom_xpos = rng.uniform(-0.2, 0.2, (ch.model.ngeom, 3))
        xmat = np.tile(np.eye(3).ravel(), (ch.model.nbody, 1))
        xmat[feet, 8] = rng.uniform(0.97, 1.0, 2)
        leaning = bool(rng.random() < 0.2)
        fell, offset = fall_rules(com, vel, touch, geom_xpos, soles, xmat, feet, leaning, vector)
        # the numpy it replaced (cmrt.sim.spatial._fallen before it was compiled)
        capture = com[:2] + vel[:2] / np.sqrt(GRAVITY_M_S2 / max(float(com[2]), 1e-3))
        on = [(n > 0.0).any() for n in (touch[:4], touch[4:])]
        sole_xy = geom_xpos[[g for foot, o in zip(soles, on, strict=True) if o for g in foot], :2]
        centre = sole_xy.mean(axis=0) if len(sole_xy) else com[:2]
        rolled = any(xmat[b, 8] < np.cos(limits.roll_rad) for b in feet)
        out = (len(sole_xy) == 0 or _margin(capture, sole_xy) < -limits.capture_margin_m) and not leaning
        assert fell == (rolled or out or com[2] < limits.com_height_m)
        np.testing.assert_array_equal(offset, capture - centre)
        seen.add(bool(fell))
    assert seen == {True, False}
