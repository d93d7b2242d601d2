"""A small store for the dashboard's tests, written through the store's own API in a fraction of a second (no
optimization): a fast-bend speed family (0.4 s and 0.6 s, the library's CMRTs as their best), one run with a
restart, and one still queued."""

import hashlib
import shutil
import threading
import time
from pathlib import Path

import pytest

from cmrt.dashboard.app import DashboardConfig, bind, create_app, url_of

POPSIZE = 4


def _finish(store, run_id: int, curve, objectives: list[list[float]]) -> None:
    """Claim run ``run_id`` and store ``objectives`` (one list per generation) as if a worker ran it."""
    from cmrt.service.store import Generation, RunProgress, StoredEvaluation

    claim = store.claim("test:1", 60.0, run_id)
    store.record_baseline(claim, 7.61, False, False)
    params = tuple(float(p) for p in curve.to_params())
    best, done = float("inf"), 0
    for gen, objs in enumerate(objectives):
        evals = [StoredEvaluation(gen, i, params, o, o > 5, o < 1, 0.01) for i, o in enumerate(objs)]
        best = min(best, *objs)
        done += len(objs)
        progress = RunProgress(done, gen + 1, int(len(objectives) > 1 and len(objectives[-1]) != POPSIZE), best,
                               params, False, best < 1, curve.to_dict(), 0.1 * done, 0.01 * len(objs))
        store.commit_generation(claim, progress, Generation(gen, 0.3, best, min(objs), params, done, time.time()),
                                evals, b"")
    store.finish(claim, "threshold", {"validation_total": 20, "validation_survived": 19, "validation_fell": 0,
                                      "min_cop_margin_m": 0.01})


def make_store(path: Path) -> Path:
    """Runs 1 (bend 0.4, done), 2 (bend 0.6, done, a restart), 3 (bend 0.4, queued)."""
    from cmrt import load_task
    from cmrt.motion.library import library_curve
    from cmrt.service.jobs import submit
    from cmrt.service.store import open_store

    bend = load_task("bend")
    with open_store(path) as s:
        for speed in (0.4, 0.6):
            submit(s, bend.with_speed(speed), init="none", max_evals=20, popsize=POPSIZE)
        submit(s, bend.with_speed(0.4), init="none", max_evals=20, popsize=POPSIZE)
        _finish(s, 1, library_curve(bend.with_speed(0.4)), [[7.9, 3.2, 9.1, 1.4], [0.9, 0.7, 6.0, 0.8]])
        _finish(s, 2, library_curve(bend.with_speed(0.6)), [[5.0, 4.0, 4.5, 4.2], [4.1, 4.0, 4.05, 4.1],
                                                            [8.0, 0.6, 9.0, 7.0, 0.5, 6.0, 9.5, 8.5]])
    return path


@pytest.fixture(scope="session")
def _template_store(tmp_path_factory) -> Path:
    return make_store(tmp_path_factory.mktemp("dashboard") / "template.sqlite")


@pytest.fixture
def store_path(_template_store, tmp_path) -> Path:
    """A private copy of the test store, at rest (no -wal, no -shm), in its own folder."""
    folder = tmp_path / "stores"
    folder.mkdir()
    shutil.copyfile(_template_store, folder / "cmrt.sqlite")
    return folder / "cmrt.sqlite"


def asgi_get(app, path: str, host: str = "127.0.0.1:8080", server: tuple[str, int] = ("127.0.0.1", 8080)
             ) -> tuple[int, bytes]:
    """GET ``path`` of the app as ASGI (no server) with this Host header, arriving at ``server``: status, body."""
    import asyncio

    scope = {"type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1", "method": "GET", "scheme": "http",
             "path": path, "raw_path": path.encode(), "query_string": b"", "root_path": "",
             "headers": [(b"host", host.encode())], "client": ("192.0.2.99", 5000), "server": server}
    sent = []

    async def receive():
        return {"type": "http.request", "body": b"", "more_body": False}

    async def send(message):
        sent.append(message)

    asyncio.run(app(scope, receive, send))
    return sent[0]["status"], b"".join(m.get("body", b"") for m in sent if m["type"] == "http.response.body")


def snapshot(path: Path) -> dict:
    """The store's bytes and its side files: what the dashboard must never change."""
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(path.parent.iterdir())
            if p.name.startswith(path.name) and p.is_file()}


class Server:
    """The dashboard served by uvicorn in a thread on a free port (a real HTTP server, in process)."""

    def __init__(self, config: DashboardConfig):
        import uvicorn

        self.sock = bind(config)
        self.url = url_of(self.sock).rstrip("/")
        self.server = uvicorn.Server(uvicorn.Config(create_app(config), log_level="warning", lifespan="off"))
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [self.sock]}, daemon=True)

    def __enter__(self):
        self.thread.start()
        deadline = time.monotonic() + 10
        while not self.server.started and time.monotonic() < deadline:
            time.sleep(0.02)
        return self

    def __exit__(self, *exc):
        self.server.should_exit = True
        self.thread.join(10)
        self.sock.close()


@pytest.fixture
def server(store_path, tmp_path):
    with Server(DashboardConfig(store_path=store_path, port=0, clip_fps=5, cache_dir=tmp_path / "clips")) as s:
        yield s
