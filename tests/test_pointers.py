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
import typing
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


def _shown_keys(text: str) -> dict[str, set[str]]:
    """Each top-level key a configuration shows (``key:`` or commented, ``# key:``),
    with the keys shown under it (at any depth, commented or not, list items too)."""
    shown: dict[str, set[str]] = {}
    current = None
    for line in text.splitlines():
        top = re.match(r"(?:# )?(\w+):", line)
        if top:
            current = top[1]
            shown.setdefault(current, set())
        elif current and (inner := re.match(r"\s*#?\s*(?:-\s+)?(\w+):", line)):
            shown[current].add(inner[1])
    return shown


def _models(kind: object) -> list[type]:
    """The pydantic models inside a type (through Optional, list, Annotated), and
    those inside their fields, at any depth."""
    from pydantic import BaseModel
    if isinstance(kind, type) and issubclass(kind, BaseModel):
        return [kind, *(m for f in kind.model_fields.values() for m in _models(f.annotation))]
    return [m for arg in typing.get_args(kind) for m in _models(arg)]


def test_nodes_yaml_shows_every_key_of_the_configuration() -> None:
    """getting-started.md says config/nodes.yaml shows every key with its default
    (commented where the section is off by default): every section and every key of
    the configuration's model is in it (issue 43: no metrics, live, mqtt, health)."""
    from gateway.daemon.config import GatewayConfig
    shown = _shown_keys((REPO / "config" / "nodes.yaml").read_text())
    missing = [f"{section}.{key}" if section in shown else section
               for section, field in GatewayConfig.model_fields.items()
               for key in ([name for model in _models(field.annotation)
                            for name in model.model_fields] or [""])
               if section not in shown or (key and key not in shown[section])]
    assert sorted(set(missing)) == []
