"""Write docs/reference/cli.md from the CLI's argument parser (every verb's --help, with its defaults).

    python tools/cli_reference.py            # rewrite docs/reference/cli.md
    python tools/cli_reference.py --check    # exit 1 if it is not current
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from cmrt.cli.commands import help_reference

OUT = Path(__file__).resolve().parent.parent / "docs" / "reference" / "cli.md"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="compare, do not write")
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)
    text = help_reference()
    if args.check:
        current = args.out.read_text() if args.out.exists() else ""
        print(f"{args.out}: {'current' if current == text else 'out of date (python tools/cli_reference.py)'}")
        return 0 if current == text else 1
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
