"""The dashboard's routes on a real store: every page and endpoint answers, bad input is a 4xx page with one
line (never a traceback), nothing outside the package's fixed list of files is served, and the store's bytes
never change."""

import http.client
import json
import os
import urllib.error
import urllib.request
from dataclasses import dataclass

import pytest

from cmrt.dashboard.app import DashboardConfig

from .conftest import Server, snapshot

PAGES = ["/", "/runs/1", "/runs/2", "/runs/3", "/compare?runs=1,2"]
ENDPOINTS = ["/api/runs", "/api/runs/1", "/api/runs/2", "/api/runs/3", "/api/runs/1/traces", "/api/compare?runs=1,2"]


@dataclass(frozen=True)
class Reply:
    status_code: int
    headers: dict
    text: str

    def json(self):
        return json.loads(self.text)


@dataclass(frozen=True)
class Client:
    """GET over real HTTP (urllib), a 4xx or 5xx returned like any answer."""

    base: str

    def get(self, url: str) -> Reply:
        try:
            with urllib.request.urlopen(self.base + url, timeout=60) as r:
                return Reply(r.status, dict(r.headers), r.read().decode())
        except urllib.error.HTTPError as exc:
            return Reply(exc.code, dict(exc.headers), exc.read().decode())


@pytest.fixture
def client(server):
    return Client(server.url)


def test_every_page_and_endpoint_answers_and_the_store_bytes_do_not_change(client, store_path):
    """Reading everything leaves the store's bytes as they were and makes no -wal or -shm beside it."""
    before = snapshot(store_path)
    assert list(before) == ["cmrt.sqlite"]  # at rest
    for url in PAGES + ENDPOINTS + ["/static/dashboard.js", "/static/dashboard.css", "/static/plotly.min.js"]:
        r = client.get(url)
        assert r.status_code == 200, (url, r.text[:200])
    assert snapshot(store_path) == before
    assert sorted(p.name for p in store_path.parent.iterdir()) == ["cmrt.sqlite"]


def test_the_runs_table_has_every_run_with_what_the_issue_lists(client):
    data = client.get("/api/runs").json()
    assert [r["id"] for r in data["runs"]] == [1, 2, 3]
    assert data["active"] is True  # run 3 is queued: the page polls
    r1 = data["runs"][0]
    assert (r1["task"], r1["speed"], r1["reference"], r1["status"]) == ("bend", 0.4, "center", "done")
    assert r1["best_objective"] == 0.7 and r1["best_success"] is True
    assert r1["improvement_over_zero"] == pytest.approx(7.61 - 0.7)
    assert r1["robustness"]["validation_survived"] == 19
    assert r1["progress"] == {**r1["progress"], "evaluations": 8, "max_evals": 20, "fraction": 0.4}
    assert data["runs"][2]["status"] == "queued" and data["runs"][2]["best_objective"] is None


def test_a_run_has_its_convergence_curves_and_task(client):
    page = client.get("/api/runs/2").json()
    c = page["convergence"]
    assert len(c["objective"]) == 16 and c["best_so_far"][-1] == 0.5 and c["threshold"] > 0
    assert c["restarts"] == [9]  # the generation of another population
    assert sum(c["success"]) == 2
    assert len(page["best_cmrt"]["knot_times_s"]) == 4 and set(page["zero_cmrt"]["displacement_cm"]) == {0.0}
    assert page["task_definition"]["name"] == "bend"
    assert page["details"]["id"] == 2


def test_the_cop_traces_and_plausibility_of_the_zero_and_best_cmrt(client):
    t = client.get("/api/runs/1/traces").json()
    zero, best = t["clips"]
    assert zero["verdict"].startswith("balance kept, not a success: ") and best["verdict"] == "SUCCESS"
    assert zero["failed_rules"] and "on time" in zero["verdict"] and best["failed_rules"] == []
    assert len(best["time_s"]) == len(best["cop_error_cm"]) <= 1500
    assert best["plausibility"]["peak_normal_force_bw"] > 1
    limits = {f["key"]: f["limit"] for f in t["plausibility_fields"]}  # every figure the verdict judges has its limit
    assert limits["max_plan_cop_error_m"] == 0.005 and limits["min_cop_margin_m"] == 0.001
    assert limits["timing_lag_s"] == pytest.approx(0.04) and limits["tracking_error_rad"] > 0
    assert client.get("/api/runs/3/traces").status_code == 404  # queued: nothing to simulate yet


def test_the_comparison_of_a_speed_family_has_its_interpolated_member(client):
    data = client.get("/api/compare?runs=2,1").json()
    assert [r["id"] for r in data["runs"]] == [2, 1]
    (member,) = data["interpolated"]
    assert member["speed"] == pytest.approx(0.5) and member["objective"] > 0
    assert "runs 1, 2" in member["label"]


@pytest.mark.parametrize("url", ["/runs/99", "/runs/0", "/runs/99999999999999999999999", "/compare?runs=1,99",
                                 "/nope", "/runs/abc", "/static/nope.js", "/clips/run99.mp4"])
def test_unknown_things_are_a_404_page(client, url):
    r = client.get(url)
    assert r.status_code == 404
    assert "text/html" in r.headers["content-type"] and "Traceback" not in r.text
    assert 'id="message"' in r.text


@pytest.mark.parametrize("url", ["/api/runs/99", "/api/runs/99/traces", "/api/compare?runs=99", "/api/nope"])
def test_unknown_things_in_the_api_are_a_404_in_json(client, url):
    r = client.get(url)
    assert r.status_code == 404 and r.json()["status"] == 404 and "\n" not in r.json()["error"]


@pytest.mark.parametrize("url", ["/compare?runs=1,x", "/api/compare?runs=-1", "/api/compare?runs=",
                                 "/api/compare?runs=" + ",".join(["1"] * 13 + ["2"])])
def test_a_bad_query_is_a_4xx(client, url):
    r = client.get(url)
    assert r.status_code in (400, 422), (url, r.status_code)
    assert "Traceback" not in r.text


def test_a_damaged_store_is_a_4xx_page_not_a_traceback(tmp_path):
    damaged = tmp_path / "cmrt.sqlite"
    damaged.write_bytes(os.urandom(8192))
    before = damaged.read_bytes()
    with Server(DashboardConfig(store_path=damaged, port=0)) as server:
        for url in ("/", "/runs/1", "/api/runs", "/api/runs/1"):
            r = Client(server.url).get(url)
            assert r.status_code == 422, url
            assert "not a CMRT store" in r.text and "Traceback" not in r.text
    truncated = tmp_path / "half.sqlite"  # an SQLite header, then nothing that holds together
    truncated.write_bytes(b"SQLite format 3\x00" + os.urandom(5000))
    with Server(DashboardConfig(store_path=truncated, port=0)) as server:
        r = Client(server.url).get("/api/runs")
    assert r.status_code == 422 and "\n" not in r.json()["error"]
    assert damaged.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cmrt.sqlite", "half.sqlite"]


@pytest.mark.parametrize("path", [
    "/static/../../etc/passwd", "/static/%2e%2e/%2e%2e/%2e%2e/etc/passwd", "/static/%2e%2e%2f%2e%2e%2fetc%2fpasswd",
    "/static/..%2f..%2fsecret.txt", "/static/%2fetc%2fpasswd", "/static//etc/passwd", "/static/../cmrt.sqlite",
    "/static/..%5c..%5csecret.txt", "/../secret.txt", "/clips/run1.mp4/../../secret.txt",
    "/static/%252e%252e/secret.txt", "/static/dashboard.js%00.txt"])
def test_a_path_outside_the_store_folder_is_a_404_and_never_read(server, store_path, path):
    """Raw request lines (http.client sends the path as written: no client normalises the dots away)."""
    secret = store_path.parent.parent / "secret.txt"
    secret.write_text("TOP SECRET")
    host, port = server.url.removeprefix("http://").split(":")
    conn = http.client.HTTPConnection(host, int(port), timeout=10)
    try:
        conn.request("GET", path)
        r = conn.getresponse()
        body = r.read().decode(errors="replace")
    finally:
        conn.close()
    assert 400 <= r.status < 500, (path, r.status)
    assert "TOP SECRET" not in body and "root:" not in body


def test_the_api_is_json_that_scripts_read(server):
    """The page and a script read the same endpoint."""
    with urllib.request.urlopen(f"{server.url}/api/runs", timeout=10) as r:
        assert r.headers["content-type"].startswith("application/json")
        assert [run["id"] for run in json.load(r)["runs"]] == [1, 2, 3]
