import hashlib
import sqlite3

import pytest

from cmrt.errors import CmrtError
from cmrt.store import SCHEMA_VERSION, open_store


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
