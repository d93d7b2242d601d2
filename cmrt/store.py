"""The SQLite store: runs (jobs), generations with optimizer checkpoints, evaluations.

Why it does not say "database is locked" with several workers:

* WAL journal: readers never block the writer and the writer never blocks readers.
* Every connection sets ``busy_timeout``; every write is one short explicit
  ``BEGIN IMMEDIATE`` transaction (the write lock is taken up front, so a
  read-then-write such as claiming a job can never deadlock on lock upgrade), and
  ``BEGIN`` itself is retried with backoff beyond the busy timeout.
* A run has exactly one writer at a time, fenced by (worker, attempt): a worker that
  lost its claim (declared stale) cannot write into the run any more.

A generation's evaluations, its optimizer checkpoint and the run's progress are
committed in one transaction, so a killed worker leaves the store at a generation
boundary: nothing half-written, nothing to duplicate on resume.

Schema changes go through ``MIGRATIONS`` (``PRAGMA user_version`` holds the version);
``meta`` marks the file as a CMRT store so a foreign SQLite file is refused untouched.
"""

from __future__ import annotations

import contextlib
import json
import os
import random
import sqlite3
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import sqlite_utils

from cmrt.errors import CmrtError

DEFAULT_STORE = Path("store") / "cmrt.sqlite"
BUSY_TIMEOUT_MS = 30_000
BEGIN_RETRIES = 20
SQLITE_MAGIC = b"SQLite format 3\x00"
APP_ID = "cmrt"

RUN_STATUSES = ("queued", "running", "done", "failed")


def _v1(db: sqlite_utils.Database) -> None:
    db["meta"].create({"key": str, "value": str}, pk="key")
    db["runs"].create(
        {
            "id": int, "task": str, "speed": float, "params": str, "task_hash": str, "task_source": str,
            "seed": int, "max_evals": int, "popsize": int, "sigma0": float, "min_evals": int,
            "stop_threshold": float, "init_run": int, "backend": str,
            "status": str, "worker": str, "attempt": int, "heartbeat_at": float,
            "created_at": float, "started_at": float, "finished_at": float,
            "best_objective": float, "best_params": str, "best_fell": int, "best_cmrt": str,
            "baseline_objective": float, "baseline_fell": int,
            "evaluations": int, "generations": int, "stop_reason": str, "wall_s": float,
            "eval_s": float, "error": str,
        },
        pk="id",
        not_null={"task", "params", "seed", "status", "created_at"},
        defaults={"status": "queued", "attempt": 0, "evaluations": 0, "generations": 0},
    )
    db["runs"].create_index(["status", "id"])
    db["runs"].create_index(["task", "speed"])
    db["generations"].create(
        {"run_id": int, "gen": int, "sigma": float, "best_objective": float, "gen_best_objective": float,
         "mean": str, "evaluations": int, "checkpoint": bytes, "created_at": float},
        pk=("run_id", "gen"),
        foreign_keys=[("run_id", "runs", "id")],
    )
    db["evaluations"].create(
        {"run_id": int, "gen": int, "idx": int, "params": str, "objective": float, "fell": int,
         "seconds": float},
        pk=("run_id", "gen", "idx"),
        foreign_keys=[("run_id", "runs", "id")],
    )


def _v2(db: sqlite_utils.Database) -> None:
    """Success (balance held, motion performed, settled) next to every objective."""
    db["runs"].add_column("best_success", int)
    db["runs"].add_column("baseline_success", int)
    db["evaluations"].add_column("success", int)


def _v3(db: sqlite_utils.Database) -> None:
    """Where a run started (warm starts), its IPOP restarts, robust ensembles and their validation."""
    db["runs"].add_column("init_source", str)  # "none", "run 12", "library (speed 0.4)"
    db["runs"].add_column("init_params", str)  # JSON: the start point itself, so a resume never re-resolves it
    db["runs"].add_column("restarts", int)
    db["runs"].add_column("stall_generations", int)  # NULL: the default (OptimizeSettings)
    db["runs"].add_column("robust", str)  # JSON: the training ensemble's specification (NULL: plain run)
    db["runs"].add_column("robustness", str)  # JSON: the best CMRT on the validation ensemble


#: MIGRATIONS[k] takes a store from version k to k + 1.
MIGRATIONS: list[Callable[[sqlite_utils.Database], None]] = [_v1, _v2, _v3]
SCHEMA_VERSION = len(MIGRATIONS)


def resolve_path(path: str | os.PathLike | None) -> Path:
    return Path(path or os.environ.get("CMRT_STORE") or DEFAULT_STORE)


def _check_is_cmrt_store(path: Path) -> None:
    """Refuse, without writing a byte, a file that is not a CMRT store."""
    with open(path, "rb") as fh:
        head = fh.read(16)
    if head != SQLITE_MAGIC:
        raise CmrtError(f"{path} is not a CMRT store (not an SQLite database)")
    try:
        con = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=BUSY_TIMEOUT_MS / 1000)
        try:
            row = con.execute("SELECT value FROM meta WHERE key = 'app'").fetchone()
            version = con.execute("PRAGMA user_version").fetchone()[0]
        finally:
            con.close()
    except sqlite3.Error:
        raise CmrtError(f"{path} is not a CMRT store (no cmrt metadata)") from None
    if not row or row[0] != APP_ID:
        raise CmrtError(f"{path} is not a CMRT store (no cmrt metadata)")
    if version > SCHEMA_VERSION:
        raise CmrtError(f"{path} has schema version {version}, newer than this cmrt ({SCHEMA_VERSION})")


class Store:
    """One connection to a CMRT store; open with :func:`open_store`."""

    def __init__(self, path: Path, readonly: bool = False):
        self.path = path
        self.readonly = readonly
        if readonly:
            conn = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=BUSY_TIMEOUT_MS / 1000)
        else:
            conn = sqlite3.connect(str(path), timeout=BUSY_TIMEOUT_MS / 1000)
        conn.execute(f"PRAGMA busy_timeout = {BUSY_TIMEOUT_MS}")
        if not readonly:
            conn.execute("PRAGMA journal_mode = WAL")
            conn.execute("PRAGMA synchronous = NORMAL")  # WAL + NORMAL: safe against process crashes
            conn.execute("PRAGMA foreign_keys = ON")
        conn.row_factory = sqlite3.Row
        self.conn = conn
        self.db = sqlite_utils.Database(conn)

    def close(self) -> None:
        self.conn.close()

    def __enter__(self) -> Store:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @contextlib.contextmanager
    def transaction(self) -> Iterator[sqlite3.Connection]:
        """BEGIN IMMEDIATE ... COMMIT, with BEGIN retried with jittered backoff."""
        for attempt in range(BEGIN_RETRIES):
            try:
                self.conn.execute("BEGIN IMMEDIATE")
                break
            except sqlite3.OperationalError as exc:
                if "locked" not in str(exc) and "busy" not in str(exc) or attempt == BEGIN_RETRIES - 1:
                    raise
                time.sleep(min(2.0, 0.05 * 2**attempt) * (0.5 + random.random()))
        try:
            yield self.conn
        except BaseException:
            self.conn.rollback()
            raise
        else:
            self.conn.commit()

    @property
    def schema_version(self) -> int:
        return int(self.conn.execute("PRAGMA user_version").fetchone()[0])

    def migrate(self) -> None:
        with self.transaction():
            version = self.schema_version  # re-read under the write lock
            for step in MIGRATIONS[version:]:
                step(self.db)
            if version == 0:
                self.db["meta"].insert_all(
                    [{"key": "app", "value": APP_ID}, {"key": "created_at", "value": str(time.time())}]
                )
            self.conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")

    # --- reads -----------------------------------------------------------------
    def run(self, run_id: int) -> dict:
        row = self.conn.execute("SELECT * FROM runs WHERE id = ?", (run_id,)).fetchone()
        if row is None:
            raise CmrtError(f"no run {run_id} in {self.path}")
        return _decode_run(dict(row))

    def runs(self, task: str | None = None, status: str | None = None) -> list[dict]:
        sql, args = "SELECT * FROM runs WHERE 1=1", []
        if task:
            sql += " AND task = ?"
            args.append(task)
        if status:
            sql += " AND status = ?"
            args.append(status)
        return [_decode_run(dict(r)) for r in self.conn.execute(sql + " ORDER BY id", args)]

    def evaluations(self, run_id: int) -> list[dict]:
        rows = self.conn.execute(
            "SELECT gen, idx, params, objective, fell, success, seconds FROM evaluations WHERE run_id = ? "
            "ORDER BY gen, idx",
            (run_id,),
        )
        return [{**dict(r), "params": json.loads(r["params"]), "fell": bool(r["fell"]),
                 "success": None if r["success"] is None else bool(r["success"])} for r in rows]

    def generations(self, run_id: int) -> list[dict]:
        rows = self.conn.execute(
            "SELECT gen, sigma, best_objective, gen_best_objective, mean, evaluations, created_at "
            "FROM generations WHERE run_id = ? ORDER BY gen",
            (run_id,),
        )
        return [{**dict(r), "mean": json.loads(r["mean"])} for r in rows]

    def successful_runs(self, task_name: str) -> list[dict]:
        """Finished runs of a task whose best CMRT is a success (warm-start candidates), oldest first."""
        rows = self.conn.execute(
            "SELECT * FROM runs WHERE task = ? AND status = 'done' AND best_success = 1 AND best_params IS NOT NULL "
            "ORDER BY id", (task_name,))
        return [_decode_run(dict(r)) for r in rows]

    def last_checkpoint(self, run_id: int) -> tuple[int, bytes] | None:
        row = self.conn.execute(
            "SELECT gen, checkpoint FROM generations WHERE run_id = ? ORDER BY gen DESC LIMIT 1", (run_id,)
        ).fetchone()
        return (int(row["gen"]), bytes(row["checkpoint"])) if row else None


def _decode_run(row: dict) -> dict:
    for key in ("params", "best_params", "best_cmrt", "init_params", "robust", "robustness"):
        if row.get(key):
            row[key] = json.loads(row[key])
    for key in ("best_fell", "baseline_fell", "best_success", "baseline_success"):
        if row.get(key) is not None:
            row[key] = bool(row[key])
    return row


def open_store(path: str | os.PathLike | None = None, *, create: bool = True, readonly: bool = False) -> Store:
    """Open (and create or migrate) a store; a foreign file is refused untouched."""
    p = resolve_path(path)
    if p.exists():
        if p.is_dir():
            raise CmrtError(f"{p} is a directory, not a CMRT store")
        if p.stat().st_size > 0:
            _check_is_cmrt_store(p)
    elif readonly or not create:
        raise CmrtError(f"no CMRT store at {p}")
    elif not p.parent.exists():
        raise CmrtError(f"cannot create store {p}: directory {p.parent} does not exist")
    try:
        store = Store(p, readonly=readonly)
        if not readonly and store.schema_version < SCHEMA_VERSION:
            store.migrate()
    except sqlite3.Error as exc:
        raise CmrtError(f"cannot open store {p}: {exc}") from None
    return store
