"""A store from anyone, fuzzed (issue 46, item 7): every column of every table holding each of ``HOSTILE``'s values,
read by every verb that reads a store, every dashboard route and a worker.

Each (table, column, value) is one copy of a small real store (the dashboard's test store: two finished runs of a
speed family and a queued one resumed from a real CMA-ES checkpoint) with that value written into the rows cmrt
reads (runs 1 and 3, the first generation and evaluation of runs 1 and 3, the ``app`` row of ``meta``). Then:

* each verb of ``READ_VERBS`` through ``cmrt.cli.main`` in this process must exit 0, or 2 with exactly one line
  ``cmrt: error: ...`` - never a traceback, never another status - and leave the store's bytes unchanged;
* each route of ``ROUTES`` of the real Starlette app (called as ASGI, no socket) must answer 200, 404 or 422 with
  one line under ``/api/`` - never a 500 - and leave the store's bytes unchanged;
* a worker (``jobs.work``) must fail the queued run with a one-line reason, or find nothing to claim, or reach
  the evaluation - where a stub stops it as Ctrl-C would and the run goes back to the queue - never raise anything
  else and never leave the run ``running``.

Values SQLite refuses to store in a column (NULL in a NOT NULL one, text as an INTEGER PRIMARY KEY) are counted and
skipped. ``simulate`` and ``render`` name another task than the run's, so they read and check the stored run and
its curve, then refuse before any physics; ``plot`` is left out (it simulates and draws each accepted variant: it
reads what ``show`` and ``export`` read). The dashboard's renderer is a stub (the clip route's reads are fuzzed, not
OpenGL). The counts are printed (``-s``) and recorded in docs/service.md.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import hashlib
import io
import json
import os
import shutil
import sqlite3
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from cmrt.cli import commands as cli
from cmrt.dashboard import data
from cmrt.dashboard.app import DashboardConfig, create_app
from cmrt.errors import CmrtError
from cmrt.motion.curve import Cmrt
from cmrt.optimize.parallel import Evaluator
from cmrt.service import records
from cmrt.sim.objective import EvalRecord

HOSTILE: dict[str, object] = {
    "NULL": None, "empty text": "", "text": "x", "blob": b"\x00\xff", "zero": 0, "-1": -1, "2**63-1": 2**63 - 1,
    "1e308": 1e308, "5e-324": 5e-324, "0.5": 0.5, "inf": float("inf"), "-inf": float("-inf"), "NaN": "NaN",
    "empty list": "[]", "list": "[1, 2]", "list of NaN": "[NaN, 1e308]", "empty dict": "{}", "dict": '{"a": 1}',
    "deep": "[" * 200 + "]" * 200, "long text": "x" * 100_000,
}
TABLES = {"runs": records.RUNS, "generations": records.GENERATIONS, "evaluations": records.EVALUATIONS,
          "meta": records.META}
READ_VERBS = [["runs"], ["jobs"], ["show", "1"], ["best", "bend", "--speed", "0.4"], ["export", "1"],
              ["export", "1", "--format", "csv"], ["simulate", "stand", "--curve", "1"],
              ["render", "stand", "--curve", "1", "--out", "{tmp}/clip.mp4"],
              ["interpolate", "bend", "--speed", "0.5", "--from", "store"]]
ROUTES = ["/", "/runs/1", "/compare?runs=1,2", "/api/runs", "/api/runs/1", "/api/runs/1/traces",
          "/api/compare?runs=1,2", "/clips/run1.mp4"]
QUEUED = 3  # the run a worker takes


def _resume(store, run_id: int) -> None:
    """Give queued run ``run_id`` one committed generation and a real checkpoint, as a worker that was stopped."""
    from cmrt.optimize.driver import new_state, step
    from cmrt.service.jobs import settings_for
    from cmrt.service.store import Generation, RunProgress, StoredEvaluation

    claim = store.claim("fuzz:1", 60.0, run_id)
    store.record_baseline(claim, 7.61, False, False)
    state = new_state(settings_for(store.run(run_id)))
    xs, recs = step(state, lambda xs: [EvalRecord(float(np.sum(np.square(x))), False, 0.01, False) for x in xs])
    store.commit_generation(
        claim, RunProgress(state.evaluations, state.generation, 0, state.best_objective,
                           tuple(state.best_x.tolist()), False, False,
                           Cmrt.zero(2.6).to_dict(), 0.1, 0.01),
        Generation(0, float(state.es.sigma), state.best_objective, min(r.objective for r in recs),
                   tuple(map(float, state.es.mean)), state.evaluations, time.time()),
        [StoredEvaluation(0, i, tuple(x.tolist()), r.objective, r.fell, r.success, r.seconds)
         for i, (x, r) in enumerate(zip(xs, recs, strict=True))], state.dumps())
    store.release(claim)


@pytest.fixture(scope="module")
def template(tmp_path_factory) -> Path:
    from cmrt.service.store import open_store
    from tests.dashboard.conftest import make_store

    path = make_store(tmp_path_factory.mktemp("fuzz") / "template.sqlite")
    with open_store(path) as store:
        _resume(store, QUEUED)
    return path


def _plant(path: Path, table: str, column: str, value: object) -> bool:
    """Write ``value`` into the rows of ``table`` cmrt reads; False if SQLite refuses to store it there."""
    where = {"runs": "id IN (1, 3)", "meta": "key = 'app'",
             "generations": f"rowid IN (SELECT min(rowid) FROM {table} GROUP BY run_id)",
             "evaluations": f"rowid IN (SELECT min(rowid) FROM {table} GROUP BY run_id)"}[table]
    con = sqlite3.connect(path)
    try:
        con.execute(f'UPDATE {table} SET "{column}" = ? WHERE {where}', (value,))
        con.commit()
        con.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        return True
    except sqlite3.IntegrityError:  # NOT NULL, UNIQUE, a primary key's type
        return False
    finally:
        con.close()


def _digest(path: Path) -> tuple:
    """What a read must not change, cheaply: the file's size, mtime and inode, and that no side file appeared (the
    bytes themselves are compared once per variant, after all its reads)."""
    st = path.stat()
    return st.st_size, st.st_mtime_ns, st.st_ino, *(Path(f"{path}{s}").exists() for s in ("-wal", "-shm", "-journal"))


def _bytes(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _verb(argv: list[str], store: Path, tmp: Path) -> str | None:
    """One read verb in this process; what was wrong, or None."""
    out, err = io.StringIO(), io.StringIO()
    before = _digest(store)
    argv = [a.format(tmp=tmp) for a in argv]
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            rc = cli.main([*argv, "--store", str(store)])
    except BaseException as exc:  # noqa: BLE001 - the fuzz counts what escapes
        return f"{argv}: raised {type(exc).__name__}: {exc}"[:300]
    lines = err.getvalue().splitlines()
    if _digest(store) != before:
        return f"{argv}: the store changed"
    if rc == 0 and not any(line.startswith("cmrt: error") for line in lines):
        return None
    if rc == 2 and len(lines) == 1 and lines[0].startswith("cmrt: error: ") and lines[0].isprintable():
        return None
    return f"{argv}: exit {rc}: {err.getvalue()[:300]!r}"


class Asgi:
    """The dashboard app called as ASGI in this process (one event loop): GET -> (status, body)."""

    def __init__(self, app):
        self.app, self.loop = app, asyncio.new_event_loop()

    def get(self, url: str) -> tuple[int, bytes]:
        path, _, query = url.partition("?")
        scope = {"type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1", "method": "GET",
                 "scheme": "http", "path": path, "raw_path": path.encode(), "query_string": query.encode(),
                 "root_path": "", "headers": [(b"host", b"127.0.0.1:8080")], "client": ("127.0.0.1", 5000),
                 "server": ("127.0.0.1", 8080)}
        sent: list[dict] = []
        requested, done = [False], asyncio.Event()

        async def receive():  # the request once; then, as a client does, nothing until the response is sent
            if not requested[0]:
                requested[0] = True
                return {"type": "http.request", "body": b"", "more_body": False}
            await done.wait()
            return {"type": "http.disconnect"}

        async def send(message):
            sent.append(message)
            if message["type"] == "http.response.body" and not message.get("more_body", False):
                done.set()

        self.loop.run_until_complete(self.app(scope, receive, send))
        return sent[0]["status"], b"".join(m.get("body", b"") for m in sent[1:])

    def close(self) -> None:
        self.loop.close()


def _route(client: Asgi, url: str, store: Path) -> str | None:
    before = _digest(store)
    try:
        status, body = client.get(url)
    except BaseException as exc:  # noqa: BLE001
        return f"{url}: raised {type(exc).__name__}: {exc}"[:300]
    if _digest(store) != before:
        return f"{url}: the store changed"
    if status not in (200, 404, 422):
        return f"{url}: {status}: {body[:200]!r}"
    if status != 200 and url.startswith("/api/"):
        message = json.loads(body)["error"]
        if "\n" in message or "Traceback" in message:
            return f"{url}: {status}: not one line: {message[:200]!r}"
    return None


class StopAtEvaluation(Evaluator):
    """Reaching the evaluation means every stored value the worker needed was accepted: stop as Ctrl-C does."""

    def __call__(self, task, xs):
        raise KeyboardInterrupt


def _worker(store: Path) -> str | None:
    from cmrt.service.jobs import work
    from cmrt.service.store import open_store

    outcome = None
    try:
        with open_store(store) as s:
            try:
                work(s, StopAtEvaluation("batch"), until_idle=True)
            except KeyboardInterrupt:
                outcome = "reached the evaluation"
    except BaseException as exc:  # noqa: BLE001 - a refused store (exit 2 from the CLI) is fine, nothing else
        if not isinstance(exc, CmrtError) or "\n" in str(exc):
            return f"worker: raised {type(exc).__name__}: {exc}"[:300]
        return None
    con = sqlite3.connect(store)
    row = con.execute("SELECT status, error FROM runs WHERE id = ?", (QUEUED,)).fetchone()
    con.close()
    if row is not None and row[0] == "running":
        return f"worker: run {QUEUED} left running ({outcome})"
    if row is not None and row[0] == "failed" and (not isinstance(row[1], str) or "\n" in row[1]):
        return f"worker: run {QUEUED} failed without a one-line reason: {row[1]!r}"[:300]
    return None


@pytest.fixture
def fast_dir(tmp_path, monkeypatch):
    """A directory in memory (/dev/shm where there is one; else the test's own): SQLite's syncs and the read verbs'
    private copies cost nothing there, the code paths are the same. Temporary files go there too."""
    base = Path("/dev/shm") if Path("/dev/shm").is_dir() and os.access("/dev/shm", os.W_OK) else tmp_path
    directory = Path(tempfile.mkdtemp(prefix="cmrt-fuzz-", dir=base))
    monkeypatch.setattr(tempfile, "tempdir", str(directory))
    yield directory
    shutil.rmtree(directory, ignore_errors=True)


def test_every_column_of_every_table_with_hostile_values(template, fast_dir, monkeypatch, capsys):
    monkeypatch.setattr(data, "render", lambda task, curve, out, *a, **k: Path(out).write_bytes(b"\0\0\0\x18ftyp"))
    # argparse builds the same parser for every call (a process builds it once): built once here
    monkeypatch.setattr(cli, "build_parser", functools.cache(cli.build_parser))
    store, scratch = fast_dir / "store.sqlite", fast_dir / "out"
    scratch.mkdir()
    client = Asgi(create_app(DashboardConfig(store_path=store, cache_dir=fast_dir / "clips")))
    counts, failures, t0 = Counter(), [], time.perf_counter()
    try:
        for table, columns in TABLES.items():
            for column in columns:
                for label, value in HOSTILE.items():
                    shutil.copyfile(template, store)
                    if not _plant(store, table, column, value):
                        counts["not storable"] += 1
                        continue
                    counts["variants"] += 1
                    where, planted = f"{table}.{column} = {label}", _bytes(store)
                    for argv in READ_VERBS:
                        counts["verb calls"] += 1
                        if (why := _verb(argv, store, scratch)) is not None:
                            failures.append(f"{where}: {why}")
                    for url in ROUTES:
                        counts["route calls"] += 1
                        if (why := _route(client, url, store)) is not None:
                            failures.append(f"{where}: {why}")
                    if _bytes(store) != planted:
                        failures.append(f"{where}: a read changed the store's bytes")
                    if table != "evaluations":  # a worker reads runs, generations (its checkpoint) and meta
                        counts["worker calls"] += 1
                        if (why := _worker(store)) is not None:
                            failures.append(f"{where}: {why}")
    finally:
        client.close()
    counts["failures"] = len(failures)
    with capsys.disabled():
        print(f"\nstore fuzz: {dict(counts)} in {time.perf_counter() - t0:.0f} s")
    assert failures == [], "\n".join(failures[:40])
    assert counts["variants"] >= 1100 and counts["verb calls"] + counts["route calls"] + counts["worker calls"] > 20_000
