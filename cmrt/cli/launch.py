"""The ``cmrt`` command's entry point: import the CLI (seconds: MuJoCo, numba, dask) with Ctrl-C handled, so
an interrupt during start-up is one line and exit 130 like an interrupt later, not a traceback."""

from __future__ import annotations

import os
import sys


def main() -> int:
    """Import and run the CLI."""
    try:
        from cmrt.cli.commands import main as cli_main  # heavy: everything the verbs need
    except KeyboardInterrupt:
        # nothing is open yet; exit at once: finalising half-imported modules (threads, atexit hooks of
        # dask/numba) could meet the interrupt again and end in a traceback or a death by SIGINT
        sys.stderr.write("cmrt: interrupted\n")
        sys.stderr.flush()
        os._exit(130)
    return cli_main()


if __name__ == "__main__":
    sys.exit(main())
