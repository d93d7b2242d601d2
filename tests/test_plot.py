import json

import matplotlib.image as mpimg

from .service_helpers import FAST_BEND, cmrt


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


def test_plot_unknown_run(tmp_path):
    store = tmp_path / "s.sqlite"
    cmrt("submit", *FAST_BEND, store=store, check=True)
    r = cmrt("plot", "1", store=store)
    assert r.returncode == 2 and "no result" in r.stderr
