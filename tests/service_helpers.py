"""Shared helpers for the optimization-service tests (real processes, real SQLite)."""

import contextlib
import os
import signal
import subprocess
import sys

import pytest

FAST_BEND = ["bend", "--speed", "0.4"]


def cmrt(*args, store=None, timeout=600, check=False):
    cmd = [sys.executable, "-m", "cmrt.cli", *args]
    if store is not None:
        cmd += ["--store", str(store)]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env={**os.environ, "CMRT_STORE": ""})
    if check:
        assert r.returncode == 0, r.stderr
    return r


def as_in_a_terminal() -> None:
    """``preexec_fn`` for a child that is sent Ctrl-C: SIGINT at its default, as a shell gives a foreground
    command. A test run started in the background (``cmd &``, nohup) has SIGINT ignored, every child inherits
    that, and Python then installs no KeyboardInterrupt handler - which is right for a background job, so cmrt
    does not undo it; the test asks what Ctrl-C in a terminal does."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def spawn_worker(store, *args, backend="batch"):
    cmd = [sys.executable, "-m", "cmrt.cli", "worker", "--store", str(store), "--backend", backend, *args]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=as_in_a_terminal)


@contextlib.contextmanager
def tiny_disk(tmp_path, size="160k"):
    """A tmpfs of ``size`` (a real full disk); skipped where mounting is not allowed."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mnt)], capture_output=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({r.stderr.decode().strip() or 'not root'})")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def fill(directory, leave_bytes: int) -> None:
    """Fill the file system of ``directory`` up to ``leave_bytes`` free."""
    st = os.statvfs(directory)
    free = st.f_bavail * st.f_frsize
    with open(directory / "filler", "wb") as fh:
        with contextlib.suppress(OSError):
            fh.write(b"\0" * max(0, free - leave_bytes))
