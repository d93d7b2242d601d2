"""The dashboard on a 3D run (the leg lift): its run page, its sideways CoP traces with the report's figures, and
its video (the zero CMRT's clip beside the best one's, each a front view over a side view: `cmrt render`)."""

import json

from cmrt.dashboard.app import DashboardConfig, create_app
from tests.dashboard.conftest import _finish, asgi_get


def test_a_leg_lift_runs_page_traces_and_clip(tmp_path):
    from cmrt import load_task
    from cmrt.motion.library import library_curve
    from cmrt.service.jobs import submit
    from cmrt.service.store import open_store

    task = load_task("leg-lift")
    path = tmp_path / "s.sqlite"
    with open_store(path) as store:
        run_id = submit(store, task, init="none", max_evals=8, popsize=4)
        _finish(store, run_id, library_curve(task), [[11.0, 9.0, 0.6, 7.0], [0.5, 6.0, 8.0, 9.0]])
    app = create_app(DashboardConfig(store_path=path, cache_dir=tmp_path / "clips"))
    assert asgi_get(app, f"/runs/{run_id}")[0] == 200
    status, body = asgi_get(app, f"/api/runs/{run_id}/traces")
    assert status == 200, body
    traces = json.loads(body)
    zero, best = traces["clips"]
    assert zero["axis"] == best["axis"] == "y" and zero["verdict"] == "lost balance" and best["verdict"] == "SUCCESS"
    assert len(best["time_s"]) == len(best["cop_error_cm"]) == len(best["support_lo_cm"])
    assert all(lo < 0.0 < hi for lo, hi in zip(best["support_lo_cm"], best["support_hi_cm"], strict=True))
    assert best["plausibility"]["timing_lag_s"] <= best["limits"]["timing_lag_s"]
    status, body = asgi_get(app, f"/clips/run{run_id}.mp4")
    assert status == 200 and len(body) > 5_000 and body[4:8] == b"ftyp"  # an MP4


def test_a_run_page_shows_a_cmrt_in_x_and_y_with_its_values_across(tmp_path):
    """A punch3d run's CMRT acts forward and sideways: the run page's best CMRT carries both curves and knots."""
    from cmrt import Cmrt, load_task
    from cmrt.service.jobs import submit
    from cmrt.service.store import open_store

    task = load_task("punch3d")
    curve = Cmrt(task.clip_s, (0.5, 1.0, 1.5, 2.0), (0.01, 0.02, 0.03, 0.0), (0.004, 0.005, 0.002, 0.001))
    path = tmp_path / "s.sqlite"
    with open_store(path) as store:
        run_id = submit(store, task, init="none", max_evals=8, popsize=4)
        _finish(store, run_id, curve, [[11.0, 9.0, 0.6, 7.0]])
    app = create_app(DashboardConfig(store_path=path, cache_dir=tmp_path / "clips"))
    status, body = asgi_get(app, f"/api/runs/{run_id}")
    assert status == 200, body
    page = json.loads(body)
    best = page["best_cmrt"]
    assert best["cross_knot_values_cm"] == [0.4, 0.5, 0.2, 0.1]
    assert len(best["cross_displacement_cm"]) == len(best["time_s"]) and max(best["cross_displacement_cm"]) > 0.4
    assert page["zero_cmrt"]["cross_displacement_cm"] == [0.0] * len(best["time_s"])


def test_a_pose_changes_traces_are_forward_and_a_two_axis_runs_carry_the_error_across(tmp_path):
    """A 3D pose change's CoP plot is along its CMRT's axis - forward (x), the heel and toe its support's edges -
    and a CMRT in x and y's (the punch) carries the sideways error too."""
    from cmrt import load_task
    from cmrt.motion.library import library_curve
    from cmrt.service.jobs import submit
    from cmrt.service.store import open_store

    path = tmp_path / "s.sqlite"
    runs = {}
    with open_store(path) as store:
        for name in ("bend3d", "punch3d"):
            task = load_task(name)
            runs[name] = submit(store, task, init="none", max_evals=8, popsize=4)
            _finish(store, runs[name], library_curve(task), [[11.0, 9.0, 0.6, 7.0]])
    app = create_app(DashboardConfig(store_path=path, cache_dir=tmp_path / "clips"))
    for name, run_id in runs.items():
        status, body = asgi_get(app, f"/api/runs/{run_id}/traces")
        assert status == 200, body
        zero, best = json.loads(body)["clips"]
        assert best["axis"] == "x" and best["verdict"] == "SUCCESS"
        assert all(lo < 0.0 < hi for lo, hi in zip(best["support_lo_cm"], best["support_hi_cm"], strict=True))
        assert max(map(abs, best["cop_error_cm"])) > 0.5  # a forward motion's error is forward
        if name == "punch3d":
            assert best["cross_axis"] == "y" and len(best["cross_cop_error_cm"]) == len(best["time_s"])
            assert max(map(abs, best["cross_cop_error_cm"])) > 0.2
        else:
            assert "cross_cop_error_cm" not in best
