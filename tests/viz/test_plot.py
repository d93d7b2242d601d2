import json
from types import SimpleNamespace

import matplotlib.image as mpimg
import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.lines import Line2D

from cmrt.cli.commands import main
from cmrt.motion.curve import Cmrt
from cmrt.motion.library import library_curve
from cmrt.motion.taskfile import load_task
from cmrt.service.jobs import submit
from cmrt.service.store import open_store
from cmrt.viz import plot
from tests.service_helpers import FAST_BEND, cmrt


@pytest.mark.slow  # an optimization run and its figures
def test_plot_writes_three_valid_pngs(tmp_path):
    store = tmp_path / "s.sqlite"
    run = json.loads(cmrt("optimize", *FAST_BEND, "--max-evals", "10", "--popsize", "5", "--json", "--no-progress",
                          store=store, check=True).stdout)
    r = cmrt("plot", str(run["run_id"]), "--out-dir", str(tmp_path / "figs"), "--json", store=store, check=True)
    files = json.loads(r.stdout)["files"]
    assert len(files) >= 3
    for f in files:
        img = mpimg.imread(f)
        assert img.ndim == 3 and img.shape[0] > 100 and img[..., :3].std() > 0.01
    text = cmrt("plot", str(run["run_id"]), "--out-dir", str(tmp_path / "figs"), "--force", store=store,
                check=True).stdout
    assert text.splitlines() == [f"wrote {f}" for f in files]  # says what it wrote


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
    assert main(["plot", str(rid), "--out-dir", str(tmp_path / "figs"), "--store", str(store)]) == 2
    assert "no result" in capsys.readouterr().err


# --- legends and falls (issue 29 item 7): the figures' artists, read from the figures the plot verbs save ------


def _key(artist):
    """What makes two artists read the same in a legend: a line's style and width, a region's fill."""
    if isinstance(artist, Line2D):
        return "line", artist.get_linestyle(), artist.get_linewidth()
    return "region", tuple(np.round(artist.get_facecolor(), 3))


def assert_legend_covers_everything(ax):
    """Every line and shaded region of ``ax`` is in its legend, itself or as the twin of one that is (the
    second support edge, the second motion window)."""
    legend = ax.get_legend()
    assert legend is not None
    shown = {t.get_text() for t in legend.get_texts()}
    artists = list(ax.lines) + list(ax.patches)
    labelled = [a for a in artists if not a.get_label().startswith("_")]
    assert {a.get_label() for a in labelled} <= shown
    keys = {_key(a) for a in labelled}
    for a in artists:
        assert a in labelled or _key(a) in keys, f"{a} is in no legend"


def _line(ax, prefix):
    (line,) = [ln for ln in ax.lines if ln.get_label().startswith(prefix)]
    return line


def test_sequence_figure_shows_the_late_zero_and_the_superposed_success():
    """four-poses with zero CMRTs keeps its balance but is late (its motions lag their references); the figure
    draws both CoP lines to the end, labelled with their verdicts, the superposed one a success."""
    fig = plot.sequence_figure("four-poses")
    try:
        top, bottom = fig.axes[:2]
        for ax in (top, bottom):
            assert_legend_covers_everything(ax)
        zero = _line(bottom, "zero CMRTs: e=")
        assert zero.get_xdata().max() > 8.0 and "(SUCCESS)" not in zero.get_label()
        assert _line(bottom, "superposed CMRTs: e=").get_xdata().max() > 8.0
        assert "(SUCCESS)" in _line(bottom, "superposed CMRTs: e=").get_label()
    finally:
        plt.close(fig)


def test_cop_error_figure_of_a_fall():
    task = load_task("punch")
    fig = plot.cop_error_figure(task, [("zero CMRT", Cmrt.zero(task.clip_s)), ("library CMRT",
                                                                               library_curve(task))])
    try:
        fallen, kept = fig.axes
        for ax in (fallen, kept):
            assert_legend_covers_everything(ax)
        assert "lost balance" in fallen.get_title() and "SUCCESS" in kept.get_title()
        fall = _line(fallen, "balance lost").get_xdata()[0]
        for line in fallen.lines[:3]:  # the CoP error and the support edges
            assert line.get_xdata().max() <= fall
        assert _line(kept, "CoP error").get_xdata().max() > task.clip_s  # no fall: the tail too
        assert any(p.get_label() == "standing tail (not scored)" for p in kept.patches)
    finally:
        plt.close(fig)


def test_a_3d_task_is_drawn_along_its_cmrts_axis():
    """A 3D task's CoP panel is along its CMRT's axis (the punch's forward, with its error across: a CMRT in x and
    y), up to its fall, within the foot points' extent; no standing tail (a 3D clip has none)."""
    task = load_task("punch3d")
    fig = plot.cop_error_figure(task, [("zero CMRT", Cmrt.zero(task.clip_s, 2)), ("library CMRT",
                                                                                  library_curve(task))])
    try:
        fallen, kept = fig.axes
        for ax in (fallen, kept):
            assert_legend_covers_everything(ax)
            assert not any(p.get_label() == "standing tail (not scored)" for p in ax.patches)
        assert "lost balance" in fallen.get_title() and "SUCCESS" in kept.get_title()
        fall = _line(fallen, "balance lost").get_xdata()[0]
        assert _line(fallen, "CoP error p - s, forward").get_xdata().max() <= fall
        along, across = _line(kept, "CoP error p - s, forward"), _line(kept, "CoP error, sideways")
        assert along.get_xdata().max() > task.clip_s - 0.01 and across.get_xdata().size == along.get_xdata().size
        lo, hi = min(kept.lines[1].get_ydata()), max(kept.lines[2].get_ydata())
        assert lo < min(along.get_ydata()) and max(along.get_ydata()) < hi  # a success: the CoP inside the feet
    finally:
        plt.close(fig)


def test_a_3d_sequence_figure_shows_the_late_zero_and_the_superposed_success():
    fig = plot.sequence_figure("four-poses-3d")
    try:
        bottom = fig.axes[1]
        assert_legend_covers_everything(bottom)
        assert "(SUCCESS)" not in _line(bottom, "zero CMRTs: e=").get_label()
        assert "(SUCCESS)" in _line(bottom, "superposed CMRTs: e=").get_label()
        assert _line(bottom, "superposed CMRTs: e=").get_xdata().max() > 7.9
    finally:
        plt.close(fig)


def test_cmrt_and_convergence_figures_have_complete_legends():
    task = load_task("bend").with_speed(0.4)
    fig = plot.cmrt_figure(task, library_curve(task))
    try:
        assert_legend_covers_everything(fig.axes[0])
    finally:
        plt.close(fig)
    punch = load_task("punch3d")  # a CMRT in x and y: both curves and both knot sets, each in the legend
    fig = plot.cmrt_figure(punch, library_curve(punch))
    try:
        assert_legend_covers_everything(fig.axes[0])
        across = _line(fig.axes[0], "best CMRT, across")
        assert max(across.get_ydata()) > 0.5  # cm: the punch's CoM toward the guard side before the launch
    finally:
        plt.close(fig)
    evals = [SimpleNamespace(objective=o, fell=f, success=s) for o, f, s in
             ((9.0, True, False), (3.0, False, False), (0.4, False, True), (0.5, False, True))]
    fig = plot.convergence_figure(evals, 0.45, "run 1")
    try:
        assert_legend_covers_everything(fig.axes[0])
    finally:
        plt.close(fig)


def test_family_figure_has_a_complete_legend():
    fig = plot.family_figure("bend")
    try:
        assert_legend_covers_everything(fig.axes[0])
    finally:
        plt.close(fig)
