"""``cmrt dashboard``'s refusals: one line on stderr, exit 2, before anything is served (in process: no server
starts). Serving itself is tested end to end in test_browser.py."""

import os
import socket

import pytest

from cmrt.cli.commands import main


def _refused(capsys, *argv) -> str:
    assert main(["dashboard", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("cmrt: error: ") and err.count("\n") == 1, err
    return err


@pytest.mark.parametrize("port", ["abc", "70000", "-1", "8080.5", "", "nan"])
def test_a_bad_port_is_one_line(capsys, store_path, port):
    assert "--port" in _refused(capsys, "--store", str(store_path), "--port", port)


def test_a_port_in_use_is_one_line(capsys, store_path):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        assert "in use" in _refused(capsys, "--store", str(store_path), "--port", str(port))


@pytest.mark.parametrize("host", ["no-such-host.invalid", "999.1.1.1", "bad host\n"])
def test_a_bad_host_is_one_line(capsys, store_path, host):
    assert "--host" in _refused(capsys, "--store", str(store_path), "--host", host, "--port", "0")


def test_a_damaged_or_missing_store_is_refused_before_serving(capsys, tmp_path):
    damaged = tmp_path / "cmrt.sqlite"
    damaged.write_bytes(os.urandom(4096))
    before = damaged.read_bytes()
    assert "not a CMRT store" in _refused(capsys, "--store", str(damaged), "--port", "0")
    assert damaged.read_bytes() == before and os.listdir(tmp_path) == ["cmrt.sqlite"]
    assert "no CMRT store" in _refused(capsys, "--store", str(tmp_path / "missing.sqlite"), "--port", "0")
    assert os.listdir(tmp_path) == ["cmrt.sqlite"]  # a read verb creates nothing
