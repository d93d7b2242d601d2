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
import errno
import functools
import json
import os
import random
import re
import shutil
import sqlite3
import stat
import tempfile
import threading
import time
import urllib.parse
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import sqlite_utils

from cmrt.errors import CmrtError, DiskFull, TransientFault
from cmrt.service.records import (
    EVALUATIONS,
    GENERATIONS,
    Generation,
    Run,
    RunProgress,
    RunSpec,
    StoredEvaluation,
    decode,
)

DEFAULT_STORE = Path("store") / "cmrt.sqlite"
BUSY_TIMEOUT_MS = 30_000
# SQLite checkpoints the WAL into the store once it holds this many pages (its default, 1000, is 4 MB). Every
# heartbeat is a commit of one page: with a short --stale-after the WAL grew by 4 MB in 3 s, which filled a
# small disk although the store itself is ~100 kB (the CI failure of the full-disk test on a slower machine).
WAL_AUTOCHECKPOINT_PAGES = 100
# A heartbeat is written at most this often, however short --stale-after is (a quarter of it otherwise).
MIN_HEARTBEAT_S = 0.05
BEGIN_RETRIES = 20
GIVE_BACK_TRIES = 6  # a run is given back after a transient fault within 0.1 + 0.2 + ... + 3.2 s of waiting
SQLITE_MAGIC = b"SQLite format 3\x00"
APP_ID = "cmrt"

#: a run is given back to the queue after a transient fault (or taken over after its worker died) at most
#: this many times; then it is failed with the reason (as optuna's RetryFailedTrialCallback bounds retries)
MAX_RETRIES = 10


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


def _v4(db: sqlite_utils.Database) -> None:
    """Transient faults (full disk, lost worker, SIGTERM, a stale heartbeat) retried a bounded number of times."""
    db["runs"].add_column("retries", int)  # NULL: none yet


def _v5(db: sqlite_utils.Database) -> None:
    """The controller's reference mode (cmrt.control.references) a run was optimized with."""
    db["runs"].add_column("reference", str)  # NULL: before schema 5, when every run used "center"


#: MIGRATIONS[k] takes a store from version k to k + 1.
MIGRATIONS: list[Callable[[sqlite_utils.Database], None]] = [_v1, _v2, _v3, _v4, _v5]
SCHEMA_VERSION = len(MIGRATIONS)


def resolve_path(path: str | os.PathLike | None) -> Path:
    """The store path: as given, else ``$CMRT_STORE``, else ``store/cmrt.sqlite``. An empty path given names no
    store (it once meant the default store, silently); an empty ``$CMRT_STORE`` is unset."""
    if path is not None and os.fspath(path) in ("", b""):
        raise CmrtError("an empty store path names no store (leave --store out for $CMRT_STORE or "
                        f"{DEFAULT_STORE})")
    return Path(path or os.environ.get("CMRT_STORE") or DEFAULT_STORE)


def _readonly_uri(path: Path, immutable: bool = False) -> str:
    """The ``file:`` URI of ``path`` opened read-only. Every character SQLite's URI parser gives a meaning
    (``?`` starts the query, ``#`` the fragment, ``%`` an escape) is percent-encoded: a store named
    ``a?b.sqlite`` is that file, not ``a`` with a query (which once made a read see an "empty" store that
    the caller then replaced)."""
    quoted = urllib.parse.quote(os.fsencode(path.absolute()), safe="/")
    return f"file:{quoted}?mode=ro" + ("&immutable=1" if immutable else "")


PROGRESS_EVERY_OPS = 10_000  # SQLite VM instructions between calls of the progress callback (~1 % overhead)


def _defensive(conn: sqlite3.Connection) -> None:
    """SQLite's defensive mode (no writable schema, no shadow-table writes), where Python exposes it: the
    ``setconfig`` of Python 3.12+. On 3.11 the schema check and ``trusted_schema = OFF`` stand alone."""
    if hasattr(conn, "setconfig") and hasattr(sqlite3, "SQLITE_DBCONFIG_DEFENSIVE"):
        conn.setconfig(sqlite3.SQLITE_DBCONFIG_DEFENSIVE, True)


def _let_signals_in() -> int:
    """The progress callback: a Python call, so the interpreter runs a pending signal handler (0: go on)."""
    return 0


def _connect_readonly(path: Path) -> sqlite3.Connection:
    """A connection that cannot write a byte. A WAL store in a directory we cannot write to cannot get its
    shared-memory file: it is then read as immutable (no writer can be working in such a directory)."""
    con = sqlite3.connect(_readonly_uri(path), uri=True, timeout=BUSY_TIMEOUT_MS / 1000)
    try:
        con.execute("PRAGMA trusted_schema = OFF")  # no SQL function runs from a schema we did not write
        con.execute("SELECT 1 FROM sqlite_master LIMIT 1").fetchall()
        return con
    except sqlite3.OperationalError as exc:
        con.close()
        if "unable to open" not in str(exc) or os.access(path.parent, os.W_OK):
            raise
    con = sqlite3.connect(_readonly_uri(path, immutable=True), uri=True, timeout=BUSY_TIMEOUT_MS / 1000)
    con.execute("PRAGMA trusted_schema = OFF")
    return con


def _wal_at_rest(path: Path) -> bool:
    """A WAL-mode SQLite file with neither ``-wal`` nor ``-shm`` beside it: no connection is open on it, and a
    reader would create both (SQLite's WAL readers need the shared-memory file) and leave them behind."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(20)
    except OSError:
        return False
    return head[:16] == SQLITE_MAGIC and head[18:20] == b"\x02\x02" and not any(
        os.path.lexists(f"{path}{side}") for side in ("-wal", "-shm"))


def _fingerprint(path: Path) -> tuple[int, int, int]:
    st = path.stat()
    return st.st_size, st.st_mtime_ns, st.st_ino


def _private_copy(path: Path) -> tempfile.TemporaryDirectory | None:
    """A private copy of a WAL store at rest, for a read verb to read (``store.sqlite`` in the returned
    directory), so that reading creates no byte beside the user's file; None when the store is not at rest
    (a writer's side files are there: reading them creates nothing new) or no copy can be made.

    The copy is consistent: at rest the main file holds every committed transaction, and a writer that starts
    during the copy writes to a new ``-wal`` (the main file changes only at a checkpoint, after it). So the copy
    is kept only if, after it, the store is still at rest and its size, mtime and inode are unchanged."""
    for _ in range(3):
        if not _wal_at_rest(path):
            return None
        try:
            before = _fingerprint(path)
            scratch = tempfile.TemporaryDirectory(prefix="cmrt-read-")
        except OSError:
            return None
        try:
            shutil.copyfile(path, Path(scratch.name) / "store.sqlite")
            if _wal_at_rest(path) and _fingerprint(path) == before:
                return scratch
        except OSError:
            pass
        scratch.cleanup()
    return None


def _inspect(path: Path, label: Path | None = None) -> str:
    """What is at ``path``, without writing a byte: "missing", "empty" (no bytes, or an SQLite file without a
    single table: a creation that failed) or "store"; CmrtError for anything else. Messages name ``label``
    (the user's path when ``path`` is a private copy of it)."""
    label = label or path
    try:
        st = path.stat()
    except FileNotFoundError:
        return "missing"
    except OSError as exc:
        raise CmrtError(f"cannot read store {label}: {exc.strerror}") from None
    if stat.S_ISDIR(st.st_mode):
        raise CmrtError(f"{label} is a directory, not a CMRT store")
    if not stat.S_ISREG(st.st_mode):
        raise CmrtError(f"{label} is not a regular file, not a CMRT store")
    if st.st_size == 0:
        return "empty"
    try:
        with open(path, "rb") as fh:
            head = fh.read(16)
    except OSError as exc:
        raise CmrtError(f"cannot read store {label}: {exc.strerror}") from None
    if head != SQLITE_MAGIC:
        raise CmrtError(f"{label} is not a CMRT store (not an SQLite database)")
    side = [Path(f"{path}-wal"), Path(f"{path}-shm")]
    existed = [p.exists() for p in side]
    try:
        con = _connect_readonly(path)
        try:
            tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
            version = con.execute("PRAGMA user_version").fetchone()[0]
            schema = _schema(con)  # before any row is read: no view, trigger or foreign column is ever touched
            row = None
            if "meta" in tables and schema.get(("table", "meta")) == _expected_schema(1)[("table", "meta")]:
                row = con.execute("SELECT value FROM meta WHERE key = 'app'").fetchone()
        finally:
            con.close()
    except sqlite3.DatabaseError as exc:
        for p, was in zip(side, existed, strict=True):  # what opening a damaged file made beside it
            if not was:
                with contextlib.suppress(OSError):
                    p.unlink()
        raise _unreadable(exc, path, label) from None
    if not tables and version == 0:
        return "empty"
    if not row or row[0] != APP_ID:
        raise CmrtError(f"{label} is not a CMRT store (no cmrt metadata)")
    if version > SCHEMA_VERSION:
        raise CmrtError(f"{label} has schema version {version}, newer than this cmrt ({SCHEMA_VERSION})")
    if schema != _expected_schema(version):
        raise CmrtError(f"{label} is not a store cmrt wrote: {_schema_difference(schema, _expected_schema(version))}")
    return "store"


#: the tokens of an SQL definition: strings, quoted identifiers ("x", [x], `x`), words, numbers, comments, symbols
_SQL_TOKENS = re.compile(r"""'(?:[^']|'')*'|"(?:[^"]|"")*"|\[[^\]]*\]|`(?:[^`]|``)*`|[A-Za-z_][A-Za-z0-9_$]*"""
                         r"""|[0-9.]+(?:[eE][+-]?[0-9]+)?|--[^\n]*|/\*.*?(?:\*/|$)|\S""", re.DOTALL)


@functools.lru_cache(maxsize=256)  # every store holds the same few definitions: each is tokenized once
def _definition(sql: str | None) -> str | None:
    """An object's SQL as SQLite reads it, written one way: tokens separated by one space, identifiers unquoted
    and in lower case (SQLite's are case-insensitive), comments dropped, string literals kept as written. Two
    definitions are the same object exactly when these are equal: a CHECK, a COLLATE, an expression or a
    WHERE that cmrt did not write is a difference, quoting and line breaks are not."""
    if sql is None:
        return None
    out = []
    for token in _SQL_TOKENS.findall(sql):
        if token.startswith(("--", "/*")):
            continue
        if token[0] in "\"[`":
            token = token[1:-1].replace(token[0] * 2, token[0]) if token[0] != "[" else token[1:-1]
            token = token.lower()
        elif token[0] != "'":
            token = token.lower()
        out.append(token)
    return " ".join(out)


def _pragma(con: sqlite3.Connection, pragma: str, columns: str, name: str) -> tuple:
    return tuple(sorted(map(tuple, con.execute(f"SELECT {columns} FROM pragma_{pragma}(?)", (name,)).fetchall()),
                        key=repr))


SQLITE_READONLY_ROLLBACK = 776  # a hot journal a read-only connection cannot roll back


def _unreadable(exc: sqlite3.DatabaseError, path: Path, label: Path) -> Exception:
    """Why SQLite could not read the file at ``path``, named as what it is: a full disk (exit 75), a hot rollback
    journal (a writer stopped mid-transaction), no permission, or damage."""
    if is_disk_full(exc, path):
        return disk_full(label)
    journal = Path(f"{path}-journal")
    if getattr(exc, "sqlite_errorcode", None) == SQLITE_READONLY_ROLLBACK or (
            journal.is_file() and journal.stat().st_size > 0 and "readonly" in str(exc)):
        return CmrtError(f"{label} has a hot rollback journal ({label}-journal): a process writing it stopped "
                         "mid-transaction; cmrt writes no store before checking it: let SQLite roll it back "
                         f"(sqlite3 {label} 'PRAGMA integrity_check') and run this again")
    if isinstance(exc, sqlite3.OperationalError) and "unable to open" in str(exc):
        return CmrtError(f"cannot open store {label} (permissions?)")
    return CmrtError(f"{label} is a corrupted SQLite file ({' '.join(str(exc).split())[:120]})")


def _schema(con: sqlite3.Connection) -> dict:
    """Every schema object of a database - (type, name) -> its table, for a table its columns as ``PRAGMA
    table_xinfo`` gives them (hidden = generated), its foreign keys and its indexes, for an index its columns
    and expressions (``index_xinfo``), and for every object its definition (:func:`_definition` of its SQL:
    CHECK constraints, index expressions, partial-index WHEREs, trigger and view bodies) - read from
    ``sqlite_master`` and pragmas only, so a hostile view, trigger or index expression is listed, never run."""
    out = {}
    for kind, name, table, sql in con.execute("SELECT type, name, tbl_name, sql FROM sqlite_master").fetchall():
        if kind == "table":
            entry: tuple = (
                table, _pragma(con, "table_xinfo", 'cid, name, type, "notnull", dflt_value, pk, hidden', name),
                _pragma(con, "foreign_key_list", '"table", "from", "to", on_update, on_delete, "match"', name),
                _pragma(con, "index_list", 'name, "unique", origin, partial', name))
        elif kind == "index":
            entry = (table, _pragma(con, "index_xinfo", 'seqno, cid, name, "desc", coll, "key"', name))
        else:
            entry = (table,)
        out[(kind, name)] = (*entry, _definition(sql))
    return out


@functools.cache
def _expected_schema(version: int) -> dict:
    """The schema cmrt's own migrations give a store of ``version`` (built in memory once per process)."""
    con = sqlite3.connect(":memory:")
    try:
        db = sqlite_utils.Database(con)
        for step in MIGRATIONS[:version]:
            step(db)
        return _schema(con)
    finally:
        con.close()


def _schema_difference(have: dict, want: dict) -> str:
    """What a foreign schema has that cmrt's does not (or lacks), in a few words."""
    extra = sorted(f"{k} {n}" for k, n in set(have) - set(want))
    missing = sorted(f"{k} {n}" for k, n in set(want) - set(have))
    changed = sorted(f"{k} {n}" for k, n in set(have) & set(want) if have[(k, n)] != want[(k, n)])
    parts = [f"unexpected {', '.join(extra)}"] * bool(extra) + [f"missing {', '.join(missing)}"] * bool(missing)
    parts += [f"a different definition of {', '.join(changed)}"] * bool(changed)
    return "; ".join(parts)[:200]


class LostClaim(RuntimeError):
    """Another worker took this run over (ours was considered dead)."""


@dataclass(frozen=True)
class Claim:
    """A worker's hold on a run: every write it makes is fenced on (worker, attempt)."""

    run_id: int
    worker: str
    attempt: int


class Store:
    """One connection to a CMRT store; open with :func:`open_store`. What a caller can rely on:

    * **Only a store cmrt wrote is opened.** Its whole schema - every object, definition by definition - is
      compared with cmrt's before any statement runs on it; anything else is a one-line CmrtError, the file
      untouched. A read-only store writes no byte (a store at rest is read from a private copy).
    * **Values are decoded, never trusted.** Reads return frozen records (``Run``, ``Generation``,
      ``StoredEvaluation``) decoded by ``records.decode``; a value outside its column's type or range raises a
      CmrtError naming the run and the column. :meth:`claim` fails such a run with that reason instead.
    * **One writer per run**, fenced on (worker, attempt) from :meth:`claim`: a write under a lost claim raises
      LostClaim and changes nothing. A generation's evaluations, checkpoint and progress commit together, so a
      killed worker leaves the run at a generation boundary. Readers see committed transactions only;
      :meth:`snapshot` holds one state across several reads.
    * **Faults of the machine**: a full disk raises DiskFull from any open, read or write and changes nothing;
      after a claim, :meth:`retry_later` can still give the run back (the space held since the claim).
    * A connection is used by one thread (the heartbeat thread opens its own).
    """

    def __init__(self, path: Path, readonly: bool = False, read_from: Path | None = None):
        self.path = path
        self.readonly = readonly
        self._scratch: tempfile.TemporaryDirectory | None = None  # a private copy read instead (open_store)
        self._reserve: int | None = None  # a descriptor holding RESERVE_BYTES beside the store, from the first claim
        if readonly:
            conn = _connect_readonly(read_from or path)
        else:
            conn = sqlite3.connect(str(path), timeout=BUSY_TIMEOUT_MS / 1000)
        try:
            self._configure(conn)
        except BaseException:
            conn.close()  # a failed open (a full disk) leaves no -wal or -shm open behind it
            raise
        conn.row_factory = sqlite3.Row
        self.conn = conn
        self.db = sqlite_utils.Database(conn)

    def _configure(self, conn: sqlite3.Connection) -> None:
        conn.execute(f"PRAGMA busy_timeout = {BUSY_TIMEOUT_MS}")
        conn.execute("PRAGMA trusted_schema = OFF")  # schema checked by _inspect; this is the second line
        # Python runs a signal handler only between bytecodes: without a callback, SIGTERM waits for a long
        # SQLite step to end. With one, the handler runs inside it and the step fails as "interrupted" (the
        # CLI and the worker then stop as the signal asked: cmrt.errors.pending_termination)
        conn.set_progress_handler(_let_signals_in, PROGRESS_EVERY_OPS)
        _defensive(conn)
        if not self.readonly:
            if conn.execute("PRAGMA journal_mode").fetchone()[0] != "wal":
                conn.execute("PRAGMA journal_mode = WAL")
            conn.execute("PRAGMA synchronous = NORMAL")  # WAL + NORMAL: safe against process crashes
            conn.execute(f"PRAGMA wal_autocheckpoint = {WAL_AUTOCHECKPOINT_PAGES}")
            conn.execute("PRAGMA foreign_keys = ON")

    def close(self) -> None:
        """Close the connection (``with open_store(...)`` does it) and delete a private copy read instead."""
        self.conn.close()
        self._release_reserve()
        if self._scratch is not None:
            self._scratch.cleanup()
            self._scratch = None

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
            self.conn.commit()
        except BaseException as exc:
            with contextlib.suppress(sqlite3.Error):
                self.conn.rollback()
            if isinstance(exc, sqlite3.Error) and is_disk_full(exc, self.path):
                raise disk_full(self.path) from exc
            raise

    @contextlib.contextmanager
    def snapshot(self) -> Iterator[None]:
        """Reads inside see one consistent state of the store (a read transaction: a writer committing
        meanwhile is not seen half-way), e.g. ``export`` while a worker runs."""
        self.conn.execute("BEGIN")
        try:
            yield
        finally:
            self.conn.rollback()

    def check_integrity(self) -> None:
        """CmrtError if SQLite's integrity check fails (a damaged file must not be written to)."""
        try:
            rows = [r[0] for r in self.conn.execute("PRAGMA integrity_check(5)")]
        except sqlite3.DatabaseError as exc:
            raise _unreadable(exc, self.path, self.path) from None
        if rows != ["ok"]:
            first = " ".join(str(rows[0]).split())[:120]  # SQLite's report spans lines: keep the error one line
            raise CmrtError(f"{self.path} is a corrupted store (integrity check: {first})")

    @property
    def schema_version(self) -> int:
        """``PRAGMA user_version``: how many MIGRATIONS the file has had."""
        return int(self.conn.execute("PRAGMA user_version").fetchone()[0])

    def migrate(self) -> None:
        """Bring the store to SCHEMA_VERSION under the write lock (a new store gets every step)."""
        with self.transaction():
            version = self.schema_version  # re-read under the write lock
            for step in MIGRATIONS[version:]:
                step(self.db)
            if version == 0:
                self.db["meta"].insert_all(
                    [{"key": "app", "value": APP_ID}, {"key": "created_at", "value": str(time.time())}]
                )
            self.conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")

    # --- writes (the job queue: cmrt.service.jobs drives them) --------------------------------
    def add_run(self, spec: RunSpec) -> int:
        """Queue a run whose whole definition is ``spec``; returns its id."""
        row = {
            "task": spec.task, "speed": spec.speed, "params": json.dumps(spec.params, sort_keys=True),
            "task_hash": spec.task_hash, "task_source": json.dumps(spec.task_definition, sort_keys=True),
            "seed": spec.seed, "max_evals": spec.max_evals, "popsize": spec.popsize, "sigma0": spec.sigma0,
            "min_evals": spec.min_evals, "stop_threshold": spec.stop_threshold, "backend": spec.backend,
            "init_run": spec.init_run, "robust": None if spec.robust is None else json.dumps(spec.robust),
            "init_source": spec.init_source,
            "init_params": None if spec.init_params is None else json.dumps(list(spec.init_params)),
            "restarts": 0, "stall_generations": spec.stall_generations, "reference": spec.reference,
            "status": "queued", "created_at": time.time(),
        }
        with self.transaction() as conn:
            cur = conn.execute(
                f"INSERT INTO runs ({', '.join(row)}) VALUES ({', '.join('?' * len(row))})", tuple(row.values())
            )
            return int(cur.lastrowid)

    def claim(self, worker: str, stale_after_s: float, run_id: int | None = None,
              on_failure: Callable[[int, str], None] | None = None) -> Claim | None:
        """Take run ``run_id`` (if claimable), else the oldest queued run, else an orphaned running one (its
        heartbeat older than ``stale_after_s``, missing, or more than ``stale_after_s`` in the future: a clock
        that went back, or a hostile value, must not hold a run for ever); None if there is none. The claim
        bumps the run's attempt: the (worker, attempt) pair fences every later write. A row that does not
        decode (a hostile or damaged value) fails that run with the reason, never the worker or the queue.
        Taking over an orphan counts as a retry; an orphan already retried ``MAX_RETRIES`` times is failed
        instead (a run that kills its worker every time must not take the queue down with it). ``on_failure(run_id,
        reason)`` is told of each run failed so, once that is committed."""
        failed: list[tuple[int, str]] = []
        self._hold_reserve()
        try:
            return self._claim(worker, stale_after_s, run_id, failed)
        finally:
            for rid, why in failed if on_failure else ():
                on_failure(rid, why)

    def _claim(self, worker: str, stale_after_s: float, run_id: int | None, failed: list) -> Claim | None:
        now = time.time()
        stale = "(status = 'running' AND (heartbeat_at IS NULL OR heartbeat_at < ? OR heartbeat_at > ?))"
        window = (now - stale_after_s, now + stale_after_s)
        with self.transaction() as conn:
            while True:
                if run_id is not None:
                    row = conn.execute(f"SELECT * FROM runs WHERE id = ? AND (status = 'queued' OR {stale})",
                                       (run_id, *window)).fetchone()
                else:
                    row = conn.execute("SELECT * FROM runs WHERE status = 'queued' ORDER BY id LIMIT 1").fetchone()
                    if row is None:
                        row = conn.execute(f"SELECT * FROM runs WHERE {stale} ORDER BY id LIMIT 1", window).fetchone()
                if row is None:
                    return None
                rid, why = row["id"], None
                try:
                    run = Run.from_row(row)
                except CmrtError as exc:
                    why = f"refused: {exc}"[:500]
                else:
                    retries = (run.retries or 0) + (run.status == "running")
                    if retries <= MAX_RETRIES:
                        break
                    why = f"gave up after {MAX_RETRIES} retries; last: {run.error or 'its worker died'}"
                conn.execute("UPDATE runs SET status = 'failed', finished_at = ?, error = ? WHERE id = ?",
                             (now, why, rid))
                failed.append((rid, why))
                if run_id is not None:
                    return None
            conn.execute(
                "UPDATE runs SET status = 'running', worker = ?, attempt = ?, heartbeat_at = ?, "
                "started_at = COALESCE(started_at, ?), retries = ? WHERE id = ?",
                (worker, run.attempt + 1, now, now, retries, rid),
            )
        return Claim(rid, worker, run.attempt + 1)

    def heartbeat(self, claim: Claim, every_s: float) -> Heartbeat:
        """``with store.heartbeat(claim, every_s):`` keeps the claimed run's heartbeat fresh meanwhile."""
        return Heartbeat(self.path, claim, every_s)

    def record_baseline(self, claim: Claim, objective: float, fell: bool, success: bool) -> None:
        """The zero CMRT's score (what the reactive controller alone does), once per run."""
        with self.transaction() as conn:
            _fenced_update(conn, claim, "baseline_objective = ?, baseline_fell = ?, baseline_success = ?, "
                           "heartbeat_at = ?", (objective, int(fell), int(success), time.time()))

    def commit_generation(self, claim: Claim, progress: RunProgress, generation: Generation,
                          evaluations: Sequence[StoredEvaluation], checkpoint: bytes) -> None:
        """One generation in one transaction: its evaluations, the optimizer checkpoint and the run's
        progress - a killed worker leaves the run at a generation boundary."""
        with self.transaction() as conn:
            _fenced_update(
                conn, claim,
                "heartbeat_at = ?, evaluations = ?, generations = ?, best_objective = ?, best_params = ?, "
                "best_fell = ?, best_success = ?, best_cmrt = ?, wall_s = ?, eval_s = COALESCE(eval_s, 0) + ?, "
                "restarts = ?",
                (generation.created_at, progress.evaluations, progress.generations, progress.best_objective,
                 json.dumps(list(progress.best_params)), int(progress.best_fell), int(progress.best_success),
                 json.dumps(progress.best_cmrt), progress.wall_s, progress.eval_s_added, progress.restarts),
            )
            conn.executemany(
                "INSERT INTO evaluations (run_id, gen, idx, params, objective, fell, success, seconds) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                [(claim.run_id, e.gen, e.idx, json.dumps(list(e.params)), e.objective, int(e.fell),
                  None if e.success is None else int(e.success), e.seconds) for e in evaluations],
            )
            conn.execute(
                "INSERT INTO generations (run_id, gen, sigma, best_objective, gen_best_objective, mean, "
                "evaluations, checkpoint, created_at) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (claim.run_id, generation.gen, generation.sigma, generation.best_objective,
                 generation.gen_best_objective, json.dumps(list(generation.mean)), generation.evaluations,
                 checkpoint, generation.created_at),
            )

    def finish(self, claim: Claim, stop_reason: str, robustness: dict) -> None:
        """Mark a claimed run done, with why it stopped and its best CMRT's validation figures."""
        now = time.time()
        with self.transaction() as conn:
            _fenced_update(conn, claim, "status = 'done', stop_reason = ?, finished_at = ?, heartbeat_at = ?, "
                           "robustness = ?", (stop_reason, now, now, json.dumps(robustness)))

    def release(self, claim: Claim) -> None:
        """Give a claimed run back to the queue (it resumes from its last checkpoint); a no-op if the claim
        was already lost."""
        with contextlib.suppress(LostClaim), self.transaction() as conn:
            _fenced_update(conn, claim, "status = 'queued', worker = NULL", ())

    def retry_later(self, claim: Claim, message: str) -> bool:
        """After a transient fault: give the run back to the queue (it resumes from its last checkpoint), or
        fail it once it has been retried MAX_RETRIES times; True once that is written (or the claim was lost
        meanwhile). On a full disk the space held since the claim (:data:`RESERVE_BYTES`) is given up for this
        write, which is then tried again for a few seconds (a file system may reuse freed blocks only after its
        journal commits); False if it still cannot be written: the run's heartbeat then goes stale and the next
        worker takes it over, counted too."""
        for attempt in range(GIVE_BACK_TRIES):
            try:
                with self.transaction() as conn:
                    self._retry_or_fail(conn, claim, message)
                return True
            except LostClaim:
                return True
            except TransientFault:
                self._release_reserve()
                time.sleep(0.1 * 2**attempt)
        return False

    def _retry_or_fail(self, conn: sqlite3.Connection, claim: Claim, message: str) -> None:
        try:
            retries = (self._run_in(conn, claim.run_id).retries or 0) + 1
        except CmrtError as exc:  # its row no longer decodes: that is its end
            _fenced_update(conn, claim, "status = 'failed', error = ?, finished_at = ?",
                           (f"refused: {exc}", time.time()))
            return
        if retries > MAX_RETRIES:
            _fenced_update(conn, claim, "status = 'failed', error = ?, finished_at = ?",
                           (f"gave up after {MAX_RETRIES} retries; last: {message}", time.time()))
        else:
            _fenced_update(conn, claim, "status = 'queued', worker = NULL, retries = ?, error = ?",
                           (retries, f"retry {retries}/{MAX_RETRIES} after: {message}"))

    def _hold_reserve(self) -> None:
        """Hold :data:`RESERVE_BYTES` beside the store (once per connection, before the first claim): a full
        disk then still lets the run be given back. No room for it is a full disk: nothing is claimed."""
        if self._reserve is None and not self.readonly:
            try:
                self._reserve = _hold_space(self.path.absolute().parent)
            except OSError:
                raise disk_full(self.path, ": no run claimed") from None

    def _release_reserve(self) -> None:
        if self._reserve is not None:
            with contextlib.suppress(OSError):
                os.ftruncate(self._reserve, 0)
            os.close(self._reserve)
            self._reserve = None

    def requeue(self, run_id: int) -> Run:
        """Put a failed run back in the queue (``cmrt requeue``): it resumes from its last checkpoint, its
        retry count starts over. A run whose row does not decode is refused before anything is written."""
        with self.transaction() as conn:
            run = self._run_in(conn, run_id)
            if run.status != "failed":
                raise CmrtError(f"run {run_id} is {run.status}: only a failed run can be requeued")
            conn.execute("UPDATE runs SET status = 'queued', worker = NULL, retries = 0, error = NULL, "
                         "finished_at = NULL WHERE id = ?", (run_id,))
        return self.run(run_id)

    def mark_failed(self, claim: Claim, message: str) -> None:
        """Mark a claimed run failed with ``message`` (a no-op if the claim was already lost)."""
        with contextlib.suppress(LostClaim), self.transaction() as conn:
            _fenced_update(conn, claim, "status = 'failed', error = ?, finished_at = ?", (message, time.time()))

    # --- reads -----------------------------------------------------------------------
    def run(self, run_id: int) -> Run:
        """The run ``run_id`` as it is now (queued, running, done or failed: ``Run.status``); CmrtError if there
        is none. ``cmrt.best_run`` is the task's best finished run instead."""
        return self._run_in(self.conn, run_id)

    def _run_in(self, conn: sqlite3.Connection, run_id: int) -> Run:
        row = conn.execute("SELECT * FROM runs WHERE id = ?", (run_id,)).fetchone()
        if row is None:
            raise CmrtError(f"no run {run_id} in {self.path}")
        return Run.from_row(row)

    def has_run(self, run_id: int) -> bool:
        """Whether run ``run_id`` exists (an unknown id in a URL is "not found", not a damaged store)."""
        return self.conn.execute("SELECT 1 FROM runs WHERE id = ?", (run_id,)).fetchone() is not None

    def runs(self, task: str | None = None, status: str | None = None, reference: str | None = None) -> list[Run]:
        """Runs, oldest first, optionally of one task name, in one status and/or with one reference mode."""
        sql, args = "SELECT * FROM runs WHERE 1=1", []
        if reference:
            sql += " AND COALESCE(reference, 'center') = ?"
            args.append(reference)
        if task:
            sql += " AND task = ?"
            args.append(task)
        if status:
            sql += " AND status = ?"
            args.append(status)
        return [Run.from_row(r) for r in self.conn.execute(sql + " ORDER BY id", args)]

    def evaluations(self, run_id: int) -> list[StoredEvaluation]:
        """Every evaluation of a run, in the order it was made."""
        rows = self.conn.execute(
            "SELECT gen, idx, params, objective, fell, success, seconds FROM evaluations WHERE run_id = ? "
            "ORDER BY gen, idx",
            (run_id,),
        )
        return [StoredEvaluation(**decode(EVALUATIONS, r, f"run {run_id}: an evaluation")) for r in rows]

    def generations(self, run_id: int) -> list[Generation]:
        """A run's generations (CMA-ES step size, mean, best so far), in order."""
        rows = self.conn.execute(
            "SELECT gen, sigma, best_objective, gen_best_objective, mean, evaluations, created_at "
            "FROM generations WHERE run_id = ? ORDER BY gen",
            (run_id,),
        )
        return [Generation(**decode(GENERATIONS, r, f"run {run_id}: a generation")) for r in rows]

    def successful_runs(self, task_name: str, reference: str = "center") -> list[Run]:
        """Finished runs of a task with this reference mode whose best CMRT is a success (warm-start candidates),
        oldest first."""
        rows = self.conn.execute(
            "SELECT * FROM runs WHERE task = ? AND status = 'done' AND best_success = 1 AND best_params IS NOT NULL "
            "AND COALESCE(reference, 'center') = ? ORDER BY id", (task_name, reference))
        return [Run.from_row(r) for r in rows]

    def best_run(self, task_hash: str) -> Run | None:
        """The best finished run of the task with this physics hash: successes first, then the lowest
        objective (the oldest on ties); None if there is none."""
        row = self.conn.execute(
            "SELECT * FROM runs WHERE status = 'done' AND task_hash = ? AND best_objective IS NOT NULL "
            "ORDER BY COALESCE(best_success, 0) DESC, best_fell ASC, best_objective ASC, id ASC LIMIT 1",
            (task_hash,),
        ).fetchone()
        return None if row is None else Run.from_row(row)

    def last_checkpoint(self, run_id: int) -> tuple[int, bytes] | None:
        """(generation, optimizer checkpoint) of the last committed generation, or None."""
        row = self.conn.execute(
            "SELECT gen, checkpoint FROM generations WHERE run_id = ? ORDER BY gen DESC LIMIT 1", (run_id,)
        ).fetchone()
        if row is None:
            return None
        values = decode(GENERATIONS, row, f"run {run_id}: its last generation")
        return values["gen"], values["checkpoint"]


class Heartbeat:
    """Refreshes a claimed run's heartbeat every ``every_s`` from a thread and a connection of its own, while
    the worker's main thread evaluates a generation: a generation longer than ``--stale-after`` no longer makes
    a healthy worker look dead (two such workers used to take one run from each other until it failed). The
    update is fenced on (worker, attempt) like every other write, so it never revives a run taken over; a
    failed beat is skipped (the main thread's next commit reports a real fault)."""

    def __init__(self, path: Path, claim: Claim, every_s: float):
        self.path, self.claim, self.every_s = path, claim, every_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._beat, name=f"heartbeat-run-{claim.run_id}", daemon=True)

    def __enter__(self) -> Heartbeat:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()

    def _beat(self) -> None:
        try:
            conn = sqlite3.connect(str(self.path), timeout=BUSY_TIMEOUT_MS / 1000)
        except sqlite3.Error:
            return
        try:
            conn.execute("PRAGMA trusted_schema = OFF")
            conn.execute(f"PRAGMA wal_autocheckpoint = {WAL_AUTOCHECKPOINT_PAGES}")
            while not self._stop.wait(max(self.every_s, MIN_HEARTBEAT_S)):
                with contextlib.suppress(sqlite3.Error):
                    conn.execute("UPDATE runs SET heartbeat_at = ? WHERE id = ? AND worker = ? AND attempt = ? "
                                 "AND status = 'running'",
                                 (time.time(), self.claim.run_id, self.claim.worker, self.claim.attempt))
                    conn.commit()
        finally:
            conn.close()


def _fenced_update(conn: sqlite3.Connection, claim: Claim, sets: str, args: tuple) -> None:
    """UPDATE the claimed run only while (worker, attempt) still hold it; LostClaim otherwise."""
    cur = conn.execute(
        f"UPDATE runs SET {sets} WHERE id = ? AND worker = ? AND attempt = ? AND status = 'running'",
        (*args, claim.run_id, claim.worker, claim.attempt),
    )
    if cur.rowcount != 1:
        raise LostClaim(f"run {claim.run_id} was taken over by another worker")


SQLITE_IOERR, SQLITE_FULL = 10, 13  # SQLite's primary result codes (the low byte of an extended one)


def _nearly_full(directory: Path, margin_bytes: int = 1 << 20) -> bool:
    """Whether the file system of ``directory`` has less than ``margin_bytes`` free (a new store needs ~100 kB)."""
    try:
        st = os.statvfs(directory)
    except OSError:
        return False
    return st.f_bavail * st.f_frsize < margin_bytes


def is_disk_full(exc: BaseException, path: Path) -> bool:
    """Whether ``exc`` means the disk is full where store ``path`` writes (beside it, or in the temporary directory
    for a private copy): ENOSPC or EDQUOT, SQLite's SQLITE_FULL, or one of SQLite's I/O errors while under 1 MB is
    free there (SQLite says "disk I/O error" when its ``-shm`` cannot grow, with 16-48 kB free)."""
    if getattr(exc, "errno", None) in (errno.ENOSPC, errno.EDQUOT):
        return True
    code = (getattr(exc, "sqlite_errorcode", None) or 0) & 0xFF
    if code == SQLITE_FULL or (isinstance(exc, sqlite3.Error) and "database or disk is full" in str(exc)):
        return True
    return code == SQLITE_IOERR and (_nearly_full(Path(path).absolute().parent)
                                     or _nearly_full(Path(tempfile.gettempdir())))


def disk_full(path: Path, then: str = "") -> DiskFull:
    """The one way a full disk is said: ``store PATH: disk full`` and what that left, exit 75."""
    return DiskFull(f"store {path}: disk full{then} (free some space and run it again)")


#: disk space a writer holds from its first claim for the write that gives its run back when the disk fills up
#: (a few pages of the WAL: the run's row and its status index)
RESERVE_BYTES = 256 * 1024


def _hold_space(directory: Path, size: int = RESERVE_BYTES) -> int | None:
    """A descriptor of an unlinked file holding ``size`` bytes of ``directory``'s file system, or None where none
    can be made (a file system without fallocate or O_TMPFILE and no temporary file: no reserve). Unlinked, it is
    never left behind: the kernel frees its space when the descriptor closes, however the process ends."""
    try:
        fd = os.open(directory, os.O_TMPFILE | os.O_RDWR, 0o600)
    except (OSError, AttributeError):
        try:
            fd, name = tempfile.mkstemp(dir=directory, prefix=".cmrt-reserve-")
            os.unlink(name)
        except OSError as exc:
            if exc.errno in (errno.ENOSPC, errno.EDQUOT):
                raise
            return None
    try:
        os.posix_fallocate(fd, 0, size)
    except OSError as exc:
        os.close(fd)
        if exc.errno in (errno.ENOSPC, errno.EDQUOT):
            raise
        return None
    return fd


def _check_replaceable(path: Path) -> None:
    """Refuse to replace anything but an empty file or an SQLite file of one page (no table in it): the last
    guard that a creation never destroys a store, whatever made the caller think it empty."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(100)
    except FileNotFoundError:
        return
    if head and not (head.startswith(SQLITE_MAGIC) and len(head) == 100 and int.from_bytes(head[28:32]) <= 1):
        raise CmrtError(f"cannot create store {path}: a non-empty file is there")


def _create(path: Path, replace: bool) -> None:
    """Create a store atomically: built in a temporary file beside ``path`` and moved into place only when
    complete, so a failure (a full disk) leaves nothing behind. ``replace``: ``path`` is an empty file (or a
    creation that failed before this version) to be replaced; otherwise a store created meanwhile by another
    process is kept."""
    if not path.parent.is_dir():
        raise CmrtError(f"cannot create store {path}: directory {path.parent} does not exist")
    tmp = None
    try:
        # the name's head only: a 251-byte store name (its "-wal" then fills NAME_MAX) still gets a temp file
        fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name[:64]}.", suffix=".creating")
        os.close(fd)
        tmp = Path(name)
        store = Store(tmp)
        try:
            store.migrate()
        finally:
            store.close()
        if replace:
            _check_replaceable(path)
            os.replace(tmp, path)
        else:
            with contextlib.suppress(FileExistsError):
                os.link(tmp, path)
    except (sqlite3.Error, OSError, TransientFault) as exc:
        if isinstance(exc, DiskFull) or is_disk_full(exc, path) or _nearly_full(path.parent):
            raise DiskFull(f"cannot create store {path}: disk full (free some space and run it again)") from None
        raise CmrtError(f"cannot create store {path}: {getattr(exc, 'strerror', None) or exc}") from None
    finally:
        if tmp is not None:
            for leftover in (tmp, Path(f"{tmp}-wal"), Path(f"{tmp}-shm")):
                with contextlib.suppress(OSError):
                    leftover.unlink()


def _open_readonly(p: Path) -> Store:
    """A read verb's store: never a byte written beside it. A WAL store at rest is read from a private copy
    (:func:`_private_copy`); any other store through a read-only connection."""
    scratch = _private_copy(p)
    source = p if scratch is None else Path(scratch.name) / "store.sqlite"
    try:
        kind = _inspect(source, label=p)
        if kind != "store":
            raise CmrtError(f"no CMRT store at {p}" + (" (the file is empty)" if kind == "empty" else ""))
        try:
            store = Store(p, readonly=True, read_from=source)
        except sqlite3.Error as exc:
            raise _cannot(exc, p, "open") from None
    except BaseException:
        if scratch is not None:
            scratch.cleanup()
        raise
    store._scratch = scratch
    return store


def _check_openable(p: Path, readonly: bool) -> None:
    """Before a byte is read: a path that exists must be a regular file (a FIFO or a device would block or be
    written), and a read finds a store, not an empty file. Writing the default store creates its directory."""
    try:
        st = os.stat(p)
    except FileNotFoundError:
        st = None
    except (OSError, ValueError) as exc:
        raise CmrtError(f"cannot open store '{p}': {getattr(exc, 'strerror', None) or exc}") from None
    if st is not None and not stat.S_ISDIR(st.st_mode) and not stat.S_ISREG(st.st_mode):
        raise CmrtError(f"'{p}' is not a CMRT store (not a regular file)")
    if st is not None and stat.S_ISREG(st.st_mode) and st.st_size == 0 and readonly:
        raise CmrtError(f"'{p}' is not a CMRT store (an empty file)")
    if not readonly and p == DEFAULT_STORE and not p.parent.exists():
        p.parent.mkdir(parents=True)


def open_store(path: str | os.PathLike | None = None, *, create: bool = True, readonly: bool = False) -> Store:
    """Open a store.

    ``readonly`` (every command that only reads): never creates, converts or writes a byte. Otherwise the
    store is opened for writing: created atomically if missing (``create``), integrity-checked, migrated.
    A foreign, corrupted or newer file is refused untouched, with a one-line CmrtError."""
    p = resolve_path(path)
    _check_openable(p, readonly)
    if readonly:
        return _open_readonly(p)
    kind = _inspect(p)
    if kind != "store" and (readonly or not create):
        raise CmrtError(f"no CMRT store at {p}" + (" (the file is empty)" if kind == "empty" else ""))
    if kind == "missing" and not readonly and create and not p.parent.is_dir():
        raise CmrtError(f"cannot create store {p}: directory {p.parent} does not exist")
    if not readonly and not (os.access(p.parent, os.W_OK) and (kind == "missing" or os.access(p, os.W_OK))):
        raise CmrtError(f"cannot write store {p}: the file or its directory is read-only (reading it still works)")
    if kind != "store":
        _create(p, replace=kind == "empty")
        if _inspect(p) != "store":
            raise CmrtError(f"cannot create store {p}")
    try:
        store = Store(p, readonly=readonly)
    except sqlite3.Error as exc:
        raise _cannot(exc, p, "open") from None
    try:
        if not readonly:
            store.check_integrity()
            if store.schema_version < SCHEMA_VERSION:
                store.migrate()
    except BaseException as exc:
        store.close()
        if isinstance(exc, sqlite3.Error):
            raise _cannot(exc, p, "write") from None
        raise
    return store


def _cannot(exc: sqlite3.Error, path: Path, what: str) -> Exception:
    """A failure to open or write store ``path``, named: a full disk (exit 75), read-only, or SQLite's words."""
    if is_disk_full(exc, path):
        return disk_full(path)
    return CmrtError(f"cannot {what} store {path}: {'read-only' if 'readonly' in str(exc) else exc}")
