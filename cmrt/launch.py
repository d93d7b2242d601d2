"""The ``cmrt`` command's entry point: import the CLI (seconds: MuJoCo, numba, dask) with Ctrl-C handled, so
an interrupt during start-up is one line and exit 130 like an interrupt later, not a traceback."""

from __future__ import annotations

import sys


def main() -> int:
    """Import and run the CLI."""
    try:
        from cmrt.cli import main as cli_main  # heavy: everything the verbs need
    except KeyboardInterrupt:
        print("cmrt: interrupted", file=sys.stderr)
        return 130
    return cli_main()


if __name__ == "__main__":
    sys.exit(main())
