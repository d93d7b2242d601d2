"""Build the Python API reference (HTML) from the code's signatures and docstrings with pdoc, and check its links.

    python tools/api_reference.py                 # build/api/cmrt.html (open it in a browser)
    python tools/api_reference.py --out DIR

It documents ``cmrt`` as a script imports it: exactly the names of ``cmrt.__all__`` (docs/reference/python-api.md
is the tour). Every in-page link must reach an anchor of the page and every relative link a file the build wrote
(``check_links``; tests/test_tools.py builds it and runs the check).
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "build" / "api"


def build(out: Path) -> Path:
    """Write the reference into ``out``; returns the page of the ``cmrt`` module."""
    import pdoc
    import pdoc.render

    pdoc.render.configure(docformat="google", show_source=False, search=True,
                          footer_text="CMRT: anticipatory balance")
    pdoc.pdoc("cmrt", output_directory=out)
    return out / "cmrt.html"


def check_links(out: Path) -> list[str]:
    """Links of the built pages that lead nowhere: an ``#anchor`` no element of its page carries, or a relative
    file the build did not write (``https:`` links are not followed)."""
    broken = []
    for page in sorted(out.rglob("*.html")):
        text = page.read_text()
        anchors = set(re.findall(r'\bid="([^"]+)"', text))
        for href in set(re.findall(r'\bhref="([^"]+)"', text)):
            if re.match(r"[a-z]+:", href):
                continue
            target, _, anchor = href.partition("#")
            if target and not (page.parent / target).exists():
                broken.append(f"{page.name}: {href}")
            elif not target and anchor and anchor not in anchors:
                broken.append(f"{page.name}: {href}")
    return broken


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=OUT, help="directory to write the HTML into")
    args = ap.parse_args(argv)
    page = build(args.out)
    broken = check_links(args.out)
    for link in broken:
        print(f"broken link: {link}", file=sys.stderr)
    print(f"wrote {page} ({page.stat().st_size // 1024} KiB); {len(broken)} broken links")
    return 1 if broken else 0


if __name__ == "__main__":
    sys.exit(main())
