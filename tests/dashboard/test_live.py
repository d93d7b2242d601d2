"""A store a worker is writing: the dashboard shows the run's progress as it goes, and answers throughout."""

import json
import time
import urllib.request

import pytest

from cmrt.dashboard.app import DashboardConfig

from ..service_helpers import FAST_BEND, cmrt, spawn_worker
from .conftest import Server, snapshot


def _get(url: str) -> dict:
    with urllib.request.urlopen(url, timeout=30) as r:
        return json.load(r)


@pytest.mark.slow
def test_a_running_job_shows_live_progress(tmp_path):
    store = tmp_path / "cmrt.sqlite"
    # the threshold stop off: the run spends its whole budget, whatever the physics lets the search find early
    cmrt("submit", *FAST_BEND, "--max-evals", "20", "--popsize", "4", "--init", "none", "--set", "stop_threshold=0",
         store=store, check=True)
    seen = []
    with Server(DashboardConfig(store_path=store, port=0)) as server:
        worker = spawn_worker(store, "--until-idle")
        try:
            deadline = time.monotonic() + 300
            while worker.poll() is None and time.monotonic() < deadline:
                (run,) = _get(f"{server.url}/api/runs")["runs"]
                seen.append((run["status"], run["progress"]["evaluations"], run["progress"]["fraction"]))
                page = _get(f"{server.url}/api/runs/1")  # the run page's data too, mid-run
                assert page["run"]["id"] == 1
                time.sleep(0.1)
        finally:
            out, err = worker.communicate(timeout=60)
        assert worker.returncode == 0, err
        final = _get(f"{server.url}/api/runs")
    running = [s for s in seen if s[0] == "running"]
    assert running, seen  # shown while the worker held it
    evaluations = [e for _, e, _ in seen]
    assert evaluations == sorted(evaluations)  # progress only goes forward
    assert any(0 < e for _, e, _ in running), seen  # a generation committed while it ran
    (run,) = final["runs"]
    assert (run["status"], run["evaluations"], final["active"]) == ("done", 20, False)
    assert run["progress"]["fraction"] == 1.0
    # the dashboard wrote nothing: once the worker is gone the store is at rest, and reading it keeps it so
    before = snapshot(store)
    with Server(DashboardConfig(store_path=store, port=0)) as server:
        for path in ("/api/runs", "/api/runs/1", "/api/runs/1/traces", "/api/compare?runs=1", "/", "/runs/1"):
            urllib.request.urlopen(server.url + path, timeout=60).read()
    assert snapshot(store) == before
