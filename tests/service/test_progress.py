"""A run's progress (``cmrt.service.progress``): lines every few generations without a terminal, a bar with one
rate where someone watches, and the API's bar on request - on a real optimization."""

import io
import re
from types import SimpleNamespace

from cmrt.motion.taskfile import load_task
from cmrt.service.jobs import optimize_now
from cmrt.service.progress import GenerationProgress, interactive
from cmrt.service.store import open_store


def _state(gen: int, popsize: int = 10) -> SimpleNamespace:
    return SimpleNamespace(generation=gen, evaluations=gen * popsize, best_objective=1.0 / gen,
                           es=SimpleNamespace(sigma=0.5))


def _shown(bar: bool, generations: int) -> str:
    """What a run of ``generations`` generations (10 evaluations, 2 s each) shows on the stream."""
    out = io.StringIO()
    progress = GenerationProgress(300, "run 7", bar=bar, stream=out)
    for gen in range(1, generations + 1):
        progress(_state(gen), [], wall_s=gen * 2.0)
    progress.close()
    return out.getvalue()


def test_without_a_terminal_a_line_every_ten_generations_with_one_rate():
    lines = _shown(False, 25).splitlines()
    assert [line.split(",")[0] for line in lines] == ["  run 7: gen 10", "  run 7: gen 20"]
    assert lines[0] == "  run 7: gen 10, 100/300 evaluations, best 0.1000, sigma 0.500, 5.0 eval/s"
    assert all(line.count("/s") == 1 for line in lines)


def test_a_bar_shows_one_rate():
    frames = [f for f in re.split(r"[\r\n]", _shown(True, 3)) if f.strip()]
    assert frames and all(f.count("/s") <= 1 for f in frames), frames
    assert "30/300" in frames[-1] and "gen 3" in frames[-1] and "5.0 eval/s" in frames[-1]


def test_a_script_is_not_an_interactive_session():
    assert not interactive()


def test_the_api_shows_a_bar_on_request(tmp_path, capsys):
    """``optimize_now(progress=True)``: a bar on stderr; by default (a script, not a prompt) nothing."""
    task = load_task("punch")
    with open_store(tmp_path / "s.sqlite") as store:
        optimize_now(store, task, init="none", max_evals=20, popsize=10, progress=True)
        assert "run 1: 100%" in capsys.readouterr().err
        optimize_now(store, task, init="none", max_evals=20, popsize=10)
        assert capsys.readouterr().err == ""
