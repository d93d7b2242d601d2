"""The dashboard serves only files it wrote, and only to pages of the address it serves (issue 46, item 4).

A real server (uvicorn on a free port) over a real store; the renderer is replaced by one that writes a few fixed
bytes (what is tested is which file is served, not the pixels; tests/dashboard/test_clips.py renders for real)."""

import http.client
import os
import sqlite3
from pathlib import Path

import pytest

from cmrt.dashboard import data
from cmrt.dashboard.app import DashboardConfig

from .conftest import Server, asgi_get

FPS = 5
RENDERED = b"\0\0\0\x18ftypmp42 rendered by the dashboard"
SECRET = b"root:x:0:0:root:/root:/bin/bash\n"


@pytest.fixture
def stub_render(monkeypatch):
    calls = []

    def render(task, curve, out, *args, **kwargs):
        calls.append(out)
        Path(out).write_bytes(RENDERED)

    monkeypatch.setattr(data, "render", render)
    return calls


@pytest.fixture
def secret(tmp_path):
    path = tmp_path / "passwd"
    path.write_bytes(SECRET)
    return path


def clip_name(store_path: Path, run_id: int = 1) -> str:
    """The name the dashboard gives run ``run_id``'s clip: known to anyone holding the store."""
    con = sqlite3.connect(store_path)
    definition, best = con.execute("SELECT task_source, best_cmrt FROM runs WHERE id = ?", (run_id,)).fetchone()
    con.close()
    import json

    return f"run{run_id}-{data._key(json.loads(definition), json.loads(best), FPS)}.mp4"


def get(url: str, path: str, host: str | None = None) -> tuple[int, bytes, str]:
    address = url.removeprefix("http://")
    con = http.client.HTTPConnection(address, timeout=60)
    con.request("GET", path, headers={"Host": address if host is None else host})
    r = con.getresponse()
    body = r.read()
    con.close()
    return r.status, body, r.getheader("content-type", "")


def test_a_symlink_in_a_cache_shipped_beside_the_store_is_not_served(store_path, tmp_path, secret, stub_render):
    """1d2cd70 answered 200 ``video/mp4`` with the bytes of /etc/passwd: the cache was ``<store>.dashboard-cache``
    and the clip's name follows from the store's contents."""
    shipped = Path(f"{store_path}.dashboard-cache")
    shipped.mkdir()
    (shipped / clip_name(store_path)).symlink_to(secret)
    with Server(DashboardConfig(store_path=store_path, port=0, clip_fps=FPS, cache_dir=tmp_path / "own")) as s:
        status, body, kind = get(s.url, "/clips/run1.mp4")
    assert (status, body, kind) == (200, RENDERED, "video/mp4") and len(stub_render) == 1
    assert secret.read_bytes() == SECRET


def _other_owner(path: Path, secret: Path) -> None:
    path.write_bytes(SECRET)
    os.chown(path, 65534, 65534)


def _hard_link(path: Path, secret: Path) -> None:
    os.link(secret, path)


def _fifo(path: Path, secret: Path) -> None:
    os.mkfifo(path)


def _writable_by_others(path: Path, secret: Path) -> None:
    path.write_bytes(SECRET)
    path.chmod(0o666)


PLANTS = {"symlink": lambda path, secret: path.symlink_to(secret), "another user's file": _other_owner,
          "hard link": _hard_link, "FIFO": _fifo, "a file others may write": _writable_by_others}


@pytest.mark.parametrize("plant", sorted(PLANTS))
def test_only_a_regular_file_the_dashboard_wrote_is_served_from_its_own_cache(store_path, tmp_path, secret,
                                                                               stub_render, plant):
    """Whatever stands under a clip's name in the cache - a symlink, a hard link, another user's file, a FIFO - is
    neither served nor followed: the clip is rendered over it (a rename: the symlink's target is untouched)."""
    if plant == "another user's file" and os.geteuid() != 0:
        pytest.skip("chown to another user needs root")
    cache = tmp_path / "own"
    cache.mkdir(mode=0o700)
    PLANTS[plant](cache / clip_name(store_path), secret)
    with Server(DashboardConfig(store_path=store_path, port=0, clip_fps=FPS, cache_dir=cache)) as s:
        status, body, _ = get(s.url, "/clips/run1.mp4")
        assert (status, body) == (200, RENDERED) and len(stub_render) == 1
        assert get(s.url, "/clips/run1.mp4")[:2] == (200, RENDERED) and len(stub_render) == 1  # now from the cache
    entry = os.lstat(cache / clip_name(store_path))
    assert entry.st_nlink == 1 and entry.st_uid == os.geteuid() and oct(entry.st_mode)[-6:] in ("100600", "100644")
    assert secret.read_bytes() == SECRET and sorted(p.name for p in cache.iterdir()) == [clip_name(store_path)]


def test_a_cache_directory_that_is_a_symlink_is_not_used(store_path, tmp_path, secret, stub_render):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir(mode=0o700)
    (elsewhere / clip_name(store_path)).symlink_to(secret)
    (tmp_path / "cache").symlink_to(elsewhere)
    with Server(DashboardConfig(store_path=store_path, port=0, clip_fps=FPS, cache_dir=tmp_path / "cache")) as s:
        status, body, _ = get(s.url, "/clips/run1.mp4")
    assert status == 503 and b"is not a directory of this user" in body and SECRET not in body
    assert stub_render == [] and sorted(p.name for p in elsewhere.iterdir()) == [clip_name(store_path)]


@pytest.mark.parametrize("path", ["/", "/api/runs", "/api/runs/1", "/clips/run1.mp4", "/static/dashboard.js"])
def test_a_request_for_another_host_name_is_refused(server, path):
    """DNS rebinding: a page of evil.example.com whose name now points at 127.0.0.1 reads through the user's
    browser whatever the dashboard answers to it. 1d2cd70 gave it the runs."""
    for host in ("evil.example.com", "evil.example.com:80", f"evil.example.com:{server.url.rsplit(':', 1)[1]}",
                 "127.0.0.1.evil.example.com", ""):
        status, body, _ = get(server.url, path, host=host)
        assert status == 400 and b"bend" not in body, (host, status, body[:200])


def test_the_address_served_and_localhost_are_answered(server):
    port = server.url.rsplit(":", 1)[1]
    for host in (f"127.0.0.1:{port}", f"localhost:{port}", "127.0.0.1", "LOCALHOST"):
        status, body, _ = get(server.url, "/api/runs", host=host)
        assert status == 200 and b'"bend"' in body, (host, status)


def test_a_wildcard_server_answers_the_address_a_request_came_in_on_and_nothing_else(store_path, tmp_path):
    """``--host 0.0.0.0`` reached at a LAN address its name does not resolve to: that address (the connection's
    own local address) is answered, another address or name is not. Called as ASGI: the address is 192.0.2.7."""
    from cmrt.dashboard.app import create_app

    app = create_app(DashboardConfig(store_path=store_path, host="0.0.0.0", cache_dir=tmp_path / "clips"))

    def status(host: str) -> int:
        return asgi_get(app, "/api/runs", host, ("192.0.2.7", 8080))[0]

    assert status("192.0.2.7:8080") == 200 and status("192.0.2.7") == 200 and status("localhost:8080") == 200
    for other in ("192.0.2.8:8080", "evil.example.com:8080", "192.0.2.7.nip.io", "[::1]x"):
        assert status(other) == 400, other
