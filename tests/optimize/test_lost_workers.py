"""A dask worker that dies under an evaluation, on a real LocalCluster: dask reruns its tasks on the worker its
nanny restarts (same scores); a task that keeps killing workers ends in dask's KilledWorker, which cmrt treats
as a transient fault (the run goes back to the queue) rather than a failed run."""

import os
import signal
import threading
import time

import numpy as np
import pytest

from cmrt.motion.taskfile import load_task
from cmrt.optimize.parallel import LOST_WORKER_ERRORS, Evaluator

TASK = load_task("bend").with_speed(0.4)


@pytest.mark.slow  # a LocalCluster
def test_a_worker_killed_mid_generation_changes_no_score():
    xs = [np.random.default_rng(i).normal(0, 0.3, 8) for i in range(24)]
    expected = Evaluator("serial")(TASK, xs)
    with Evaluator("dask", workers=1) as ev:
        pids = list(ev._client.run(os.getpid).values())
        result: dict = {}
        thread = threading.Thread(target=lambda: result.update(out=ev(TASK, xs)))
        thread.start()
        time.sleep(0.5)
        for pid in pids:
            os.kill(pid, signal.SIGKILL)
        thread.join(300)
        assert list(ev._client.run(os.getpid).values()) != pids  # the nanny started a new worker process
    assert [r.objective for r in result["out"]] == [r.objective for r in expected]


@pytest.mark.slow  # a LocalCluster
def test_a_task_that_keeps_killing_workers_is_a_transient_fault():
    import dask  # here: importing dask costs the fast test loop a second at collection

    with dask.config.set({"distributed.scheduler.allowed-failures": 0}), Evaluator("dask", workers=1) as ev:
        future = ev._client.submit(os._exit, 1, pure=False)
        with pytest.raises(Exception) as info:
            future.result(timeout=120)
    assert type(info.value).__name__ == "KilledWorker" and "KilledWorker" in LOST_WORKER_ERRORS


def _children(pid: int) -> set[int]:
    """The pids whose parent is ``pid`` (Linux /proc)."""
    out = set()
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as fh:
                    ppid = int(fh.read().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue
            if ppid == pid:
                out.add(int(entry))
    return out


def _alive(pids: set[int]) -> set[int]:
    alive = set()
    for pid in pids:
        try:
            with open(f"/proc/{pid}/stat") as fh:
                if fh.read().rsplit(")", 1)[1].split()[0] != "Z":
                    alive.add(pid)
        except OSError:
            pass
    return alive


@pytest.mark.slow  # a worker process and its loky pool
@pytest.mark.skipif(not os.path.isdir("/proc"), reason="reads /proc")
def test_kill_9_of_a_worker_ends_its_loky_children(tmp_path):
    """1d2cd70: ``kill -9`` of ``cmrt worker --backend loky --workers 2`` left its 4 children (two 240 MB workers and
    loky's two resource trackers) running, still alive 90 s later. Its workers now die with it (PR_SET_PDEATHSIG),
    and the trackers end once no worker holds their pipe."""
    import subprocess
    import sys

    from cmrt.service.jobs import submit
    from cmrt.service.store import open_store

    path = tmp_path / "s.sqlite"
    with open_store(path) as store:  # a search that runs for minutes: no threshold stop
        submit(store, TASK.with_params(stop_threshold=0.0), init="none", popsize=8, max_evals=4000,
               min_evals=4000)
    worker = subprocess.Popen([sys.executable, "-m", "cmrt.cli", "worker", "--until-idle", "--backend", "loky",
                               "--workers", "2", "--store", str(path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        deadline = time.time() + 180
        children: set[int] = set()
        while time.time() < deadline and len(children) < 4:  # two workers, two resource trackers
            time.sleep(0.2)
            children = _children(worker.pid)
        assert len(children) >= 3, children
        time.sleep(1.0)  # the workers are scoring a generation
        worker.kill()
        worker.wait(30)
        deadline = time.time() + 10
        while time.time() < deadline and _alive(children):
            time.sleep(0.1)
        assert _alive(children) == set()
    finally:  # survivors (a failed run): SIGTERM first, so that loky's trackers still clean /dev/shm
        for sig in (signal.SIGTERM, signal.SIGKILL):
            for pid in _alive(children) if "children" in locals() else ():
                os.kill(pid, sig)
            time.sleep(1.0 if sig == signal.SIGTERM and "children" in locals() and _alive(children) else 0.0)
        if worker.poll() is None:
            worker.kill()
        worker.communicate()
