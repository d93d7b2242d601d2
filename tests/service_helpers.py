"""Shared helpers for the optimization-service tests (real processes, real SQLite)."""

import os
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


def spawn_worker(store, *args, backend="batch"):
    cmd = [sys.executable, "-m", "cmrt.cli", "worker", "--store", str(store), "--backend", backend, *args]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
