import os

# Small matrices: BLAS threads only add overhead and nondeterministic scheduling.
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import pytest  # noqa: E402


@pytest.fixture
def queued_store(tmp_path):
    """A real store file holding one queued fast-bend run (run 1), nothing optimized."""
    from cmrt import load_task
    from cmrt.service.jobs import submit
    from cmrt.service.store import open_store

    path = tmp_path / "s.sqlite"
    with open_store(path) as s:
        submit(s, load_task("bend").with_speed(0.4), init="none")
    return path
