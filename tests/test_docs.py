"""The README leads and the docs hold together: short, every link resolves, no issue numbers for users."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
LINK = re.compile(r"\]\(([^)\s]+)\)")


def test_the_readme_is_short():
    assert len((ROOT / "README.md").read_bytes()) < 12_000


def test_every_relative_link_resolves():
    broken = []
    for page in PAGES:
        for target in LINK.findall(page.read_text()):
            if re.match(r"^(https?:|mailto:|#)", target):
                continue
            path = target.split("#")[0]
            if not (page.parent / path).exists():
                broken.append(f"{page.relative_to(ROOT)}: {target}")
    assert broken == []


def test_user_docs_carry_no_issue_numbers():
    """History (which issue did what) is in CHANGELOG.md and git log, not in what a user reads."""
    found = [f"{page.relative_to(ROOT)}: {m.group(0)}" for page in PAGES
             for m in re.finditer(r"\bissues? \d+", page.read_text())]
    assert found == []


def test_the_readme_names_the_two_commands_and_the_docs_map():
    text = (ROOT / "README.md").read_text()
    assert "make demo" in text and "make test" in text and "docs/index.md" in text
