"""The ``cmrt`` command: argument parsing and printing over the public API (``commands``), and the console
script's entry point (``launch``). ``python -m cmrt.cli`` runs the command.

Importing this package loads nothing heavy: ``launch`` imports ``commands`` (MuJoCo, numba, dask come with
its verbs) only inside its ``main``, so that a Ctrl-C during start-up is handled.
"""

from __future__ import annotations


def main(argv: list[str] | None = None) -> int:
    """Run the command with ``argv`` (default: ``sys.argv[1:]``); its exit status."""
    from cmrt.cli.commands import main as run

    return run(argv)
