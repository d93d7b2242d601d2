import json

import matplotlib.image as mpimg
import pytest

from cmrt.cli.commands import main
from cmrt.motion.taskfile import load_task
from cmrt.service.jobs import submit
from cmrt.service.store import open_store
from tests.service_helpers import FAST_BEND, cmrt


@pytest.mark.slow  # an optimization run and its figures
def test_plot_writes_three_valid_pngs(tmp_path):
    store = tmp_path / "s.sqlite"
    run = json.loads(cmrt("optimize", *FAST_BEND, "--max-evals", "10", "--popsize", "5", "--json", "--no-progress",
                          store=store, check=True).stdout)
    r = cmrt("plot", str(run["run_id"]), "--out", str(tmp_path / "figs"), "--json", store=store, check=True)
    files = json.loads(r.stdout)["files"]
    assert len(files) >= 3
    for f in files:
        img = mpimg.imread(f)
        assert img.ndim == 3 and img.shape[0] > 100 and img[..., :3].std() > 0.01


@pytest.mark.slow  # two cmrt processes
def test_plot_unknown_run(tmp_path):
    store = tmp_path / "s.sqlite"
    cmrt("submit", *FAST_BEND, store=store, check=True)
    r = cmrt("plot", "1", store=store)
    assert r.returncode == 2 and "no result" in r.stderr


def test_plot_unknown_run_in_process(tmp_path, capsys):
    """The same refusal through ``cmrt.cli.main`` in this process (a queued run has nothing to plot)."""
    store = tmp_path / "s.sqlite"
    with open_store(store) as s:
        rid = submit(s, load_task("bend").with_speed(0.4), init="none")
    assert main(["plot", str(rid), "--out", str(tmp_path / "figs"), "--store", str(store)]) == 2
    assert "no result" in capsys.readouterr().err
