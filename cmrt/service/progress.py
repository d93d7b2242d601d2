"""A run's progress as it goes: a bar where someone watches, a line every few generations where no one does.

A generation of the paper's tasks takes 1-10 s, a run minutes; silence that long reads as a hang. The callback is
the ``on_generation`` of ``jobs.optimize_now``/``work``/``optimize_family`` - (state, records, wall_s) after every
committed generation - and shows one rate per line: evaluations per second over the run so far (a bar's own
smoothed rate is switched off, so two rates never disagree on one line).
"""

from __future__ import annotations

import sys
from typing import TextIO

LINE_EVERY_GENERATIONS = 10  # without a terminal: a line each this many generations (the run's end has its own)


def interactive() -> bool:
    """A person watching: a Python prompt or a Jupyter/IPython session (not a script, a pipe or a test)."""
    if hasattr(sys, "ps1"):
        return True
    shell = sys.modules.get("IPython")
    return shell is not None and getattr(shell, "get_ipython", lambda: None)() is not None


class GenerationProgress:
    """Progress of one run toward its budget of ``total_evals`` evaluations, labelled ``label`` ("run 3").

    ``bar``: a tqdm bar (``tqdm.auto``: a widget in a notebook) on ``stream``; otherwise a plain line every
    ``every`` generations. Call :meth:`close` when the run ends."""

    def __init__(self, total_evals: int, label: str, *, bar: bool, every: int = LINE_EVERY_GENERATIONS,
                 stream: TextIO | None = None):
        self.label, self.total, self.every = label, total_evals, max(1, every)
        self.stream = sys.stderr if stream is None else stream
        self.bar = None
        self.last_line_gen = 0
        if bar:
            from tqdm.auto import tqdm  # only runs that show a bar pay for it

            self.bar = tqdm(total=total_evals, unit="eval", file=self.stream, dynamic_ncols=True, desc=label,
                            bar_format="{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} [{elapsed}<{remaining}"
                                       "{postfix}]")

    def text(self, state, wall_s: float) -> str:
        """The figures after a generation: generation, evaluations of the budget, best objective, step size, and
        the run's one rate."""
        rate = state.evaluations / wall_s if wall_s > 0 else float("nan")
        return (f"gen {state.generation}, {state.evaluations}/{self.total} evaluations, best "
                f"{state.best_objective:.4f}, sigma {state.es.sigma:.3f}, {rate:.1f} eval/s")

    def __call__(self, state, records, wall_s: float) -> None:
        if self.bar is not None:
            if state.evaluations < self.bar.n:  # the next member of a family
                self.bar.reset(total=self.total)
            self.bar.n = min(state.evaluations, self.total)
            rate = state.evaluations / wall_s if wall_s > 0 else float("nan")
            self.bar.set_postfix_str(f"gen {state.generation}, best {state.best_objective:.4f}, sigma "
                                     f"{state.es.sigma:.3f}, {rate:.1f} eval/s", refresh=True)
            return
        if state.generation - self.last_line_gen >= self.every or state.generation < self.last_line_gen:
            self.last_line_gen = state.generation
            print(f"  {self.label}: {self.text(state, wall_s)}", file=self.stream, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
