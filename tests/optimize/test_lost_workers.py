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
