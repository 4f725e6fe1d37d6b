"""Every pointer to the documentation in what the project ships reaches a page and a
section that exist: the example configurations, the deployment files, the docs, README
and the code's messages and docstrings (the wheel ships them all: gx2-gateway --files).
A pointer is a page, ``README.md`` or ``docs/PAGE.md`` (``PAGE.md`` inside docs/), then
at will ``#anchor``, ``, section N`` (a numbered heading) or ``, "Heading"`` (or a
heading unquoted, up to the punctuation after it: ``(docs/operating.md, Security)``).
test_docs.py checks the Markdown links; this, the words (issue 31: config/nodes.yaml
pointed to README sections that had moved to docs/)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests.test_docs import DOCS, REPO, anchors, slug

SHIPPED = sorted([REPO / "README.md", *DOCS.glob("*.md"), *(REPO / "config").glob("*.yaml"),
                  *(p for p in (REPO / "deploy").iterdir() if p.is_file()),
                  *(REPO / "gateway").rglob("*.py"), *(REPO / "aspp").rglob("*.py")])
POINTER = re.compile(
    r"(?<![\w/.-])(?P<page>(?:docs/)?[a-z][a-z-]*\.md|README(?:\.md)?)(?![\w-])"
    r"(?:#(?P<anchor>[\w-]+)"
    r"|,\s+sections?\s+(?P<sections>\d+(?:(?:,\s*|\s+and\s+)\d+)*)"
    r"|,\s+\"(?P<heading>[^\"]+)\""
    r"|,\s+(?P<unquoted>[A-Z][\w ]*\w))?")
OWN_SECTION = re.compile(r"(?<![\w,] )\bsections?\s+(?P<sections>\d+(?:\s+and\s+\d+)*)")
"""In the interface page, a section of its own."""


def page_of(name: str, where: Path) -> Path | None:
    if name.startswith("README"):
        return REPO / "README.md"
    for candidate in (REPO / name, DOCS / name):
        if candidate.is_file():
            return candidate
    return None


def numbered(page: Path, number: str) -> bool:
    return any(anchor.startswith(f"{number}-") for anchor in anchors(page))


def problems_in(path: Path) -> list[str]:
    text = path.read_text(encoding="utf-8")
    found = []
    for match in POINTER.finditer(text):
        line = text.count("\n", 0, match.start()) + 1
        what = f"{path.relative_to(REPO)}:{line}: {match.group(0)!r}"
        page = page_of(match["page"], path)
        if page is None:
            found.append(f"{what}: no such page")
        elif match["anchor"] and match["anchor"] not in anchors(page):
            found.append(f"{what}: no such heading in {page.name}")
        elif match["sections"] and not all(numbered(page, n)
                                           for n in re.findall(r"\d+", match["sections"])):
            found.append(f"{what}: no such section in {page.name}")
        elif (heading := match["heading"] or match["unquoted"]) and \
                slug(heading) not in anchors(page):
            found.append(f"{what}: no such heading in {page.name}")
    if path == DOCS / "interface.md":
        for match in OWN_SECTION.finditer(text):
            if not all(numbered(path, n) for n in re.findall(r"\d+", match["sections"])):
                line = text.count("\n", 0, match.start()) + 1
                found.append(f"interface.md:{line}: {match.group(0)!r}: no such section")
    return found


def test_the_pointers_are_found() -> None:
    """The pattern finds each form (a test of the test)."""
    forms = ['(README, Security)', 'README.md, "Deploying"', "docs/live.md#the-live-view",
             "docs/interface.md, section 3", 'operating.md, "Security"']
    assert [m["page"] for f in forms for m in POINTER.finditer(f)] == [
        "README", "README.md", "docs/live.md", "docs/interface.md", "operating.md"]


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: str(p.relative_to(REPO)))
def test_every_pointer_reaches_its_page_and_section(path: Path) -> None:
    assert problems_in(path) == []


@pytest.mark.parametrize("path", sorted((REPO / "config").glob("*.yaml")), ids=lambda p: p.name)
def test_the_example_configurations_speak_to_their_user(path: Path) -> None:
    """No "added:" (once: a key beyond a first design, which means nothing to a user)."""
    assert not re.search(r"#.*\badded\b", path.read_text(), re.IGNORECASE)
