import hashlib
import json
import sqlite3

import pytest

from cmrt.errors import CmrtError
from cmrt.service.store import SCHEMA_VERSION, open_store
from tests.service_helpers import cmrt


def digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_new_store_is_wal_versioned_and_marked(tmp_path):
    path = tmp_path / "s.sqlite"
    with open_store(path) as store:
        assert store.schema_version == SCHEMA_VERSION
        assert store.conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        assert store.conn.execute("PRAGMA busy_timeout").fetchone()[0] >= 10_000
        assert {"runs", "generations", "evaluations", "meta"} <= set(store.db.table_names())
    with open_store(path) as again:  # reopening does not migrate twice
        assert again.schema_version == SCHEMA_VERSION


@pytest.mark.parametrize("content", [b"hello, not a database", None])
def test_foreign_files_are_refused_untouched(tmp_path, content):
    path = tmp_path / "foreign.sqlite"
    if content is None:  # a real SQLite database that is not a CMRT store
        con = sqlite3.connect(path)
        con.execute("CREATE TABLE t (x)")
        con.commit()
        con.close()
    else:
        path.write_bytes(content)
    before = digest(path)
    with pytest.raises(CmrtError, match="not a CMRT store"):
        open_store(path)
    assert digest(path) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["foreign.sqlite"]


def test_missing_store_for_queries_and_missing_directory(tmp_path):
    with pytest.raises(CmrtError, match="no CMRT store"):
        open_store(tmp_path / "none.sqlite", create=False)
    with pytest.raises(CmrtError, match="does not exist"):
        open_store(tmp_path / "nodir" / "s.sqlite")


def test_transaction_rolls_back_on_error(tmp_path):
    with open_store(tmp_path / "s.sqlite") as store:
        with pytest.raises(RuntimeError):
            with store.transaction() as conn:
                conn.execute("INSERT INTO meta (key, value) VALUES ('x', 'y')")
                raise RuntimeError("boom")
        assert store.conn.execute("SELECT COUNT(*) FROM meta WHERE key = 'x'").fetchone()[0] == 0


# A store path is a file name, never a URI: SQLite's URI parser gives ``?``, ``#`` and ``%`` a meaning. These
# once made a read see an "empty" store that the caller then replaced (`cmrt submit` on ``a?b.sqlite`` lost
# its two runs). Every name a Linux file system allows must work, as created and as copied in.
ODD_NAMES = ["a?b.sqlite", "a#b.sqlite", "x%41y.sqlite", "%3F.sqlite", "with space.sqlite", "ünï cødé ☃.sqlite",
             "-lead.sqlite", "semi;colon&amp=1.sqlite", "q" * 244 + ".sqlite"]  # 251 bytes: with "-wal", NAME_MAX


def _queue(path, n):
    from cmrt import load_task
    from cmrt.service.jobs import submit

    with open_store(path) as store:
        for _ in range(n):
            submit(store, load_task("bend").with_speed(0.4), init="none")


@pytest.mark.parametrize("name", ODD_NAMES, ids=range(len(ODD_NAMES)))
def test_a_store_path_of_any_shape_is_that_file(tmp_path, name):
    plain = tmp_path / "plain.sqlite"
    _queue(plain, 2)
    odd = tmp_path / name
    odd.write_bytes(plain.read_bytes())  # a store copied in under the odd name (no WAL side files)
    _queue(odd, 1)  # added to the existing store, not a new one in its place
    with open_store(odd, readonly=True) as store:
        assert len(store.runs()) == 3
    fresh = tmp_path / ("new " + name)[:251]
    _queue(fresh, 1)  # created under the odd name
    with open_store(fresh, readonly=True) as store:
        assert len(store.runs()) == 1
    assert sorted(p.name for p in tmp_path.iterdir() if "creating" in p.name) == []


def test_creation_never_replaces_a_non_empty_file(tmp_path):
    """The last guard: whatever made open_store think a file empty, _create refuses to replace a store."""
    from cmrt.service.store import _create

    path = tmp_path / "s.sqlite"
    _queue(path, 2)
    before = digest(path)
    with pytest.raises(CmrtError, match="a non-empty file is there"):
        _create(path, replace=True)
    assert digest(path) == before
    empty = tmp_path / "empty.sqlite"
    empty.write_bytes(b"")
    _create(empty, replace=True)  # an empty file is what replace is for
    with open_store(empty, readonly=True) as store:
        assert store.runs() == []


def test_cli_submit_on_an_odd_store_name_adds_to_it(tmp_path):
    plain = tmp_path / "s.sqlite"
    _queue(plain, 2)
    odd = tmp_path / "a?b.sqlite"
    odd.write_bytes(plain.read_bytes())
    r = cmrt("submit", "bend", "--store", str(odd))
    assert r.returncode == 0, r.stderr
    r = cmrt("runs", "--json", "--store", str(odd))
    assert r.returncode == 0 and len(json.loads(r.stdout)) == 3
