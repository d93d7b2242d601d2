"""Shared helpers for the optimization-service tests (real processes, real SQLite)."""

import os
import signal
import subprocess
import sys

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
