"""The documentation a newcomer follows: README is a front page, every link in it and in
docs/ reaches its page and heading, every page is on the site, and the map of the tree
in docs/development.md names every module there is and nothing that is gone. (CI also
builds the site with ``mkdocs build --strict``, which checks the pages' links again.)"""

from __future__ import annotations

import re
import unicodedata
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"
PAGES = sorted(DOCS.glob("*.md"))
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"^```.*?^```", re.MULTILINE | re.DOTALL)


def slug(heading: str) -> str:
    """A heading's anchor as Python-Markdown's toc makes it (MkDocs' default): code
    marks and punctuation dropped, lower case, spaces to hyphens."""
    text = unicodedata.normalize("NFKD", heading).encode("ascii", "ignore").decode()
    text = re.sub(r"[^\w\s-]", "", text).strip().lower()
    return re.sub(r"[-\s]+", "-", text)


def anchors(page: Path) -> set[str]:
    text = FENCE.sub("", page.read_text())
    return {slug(m.group(1)) for m in re.finditer(r"^#{1,6} (.+)$", text, re.MULTILINE)}


def links(page: Path) -> list[str]:
    return LINK.findall(FENCE.sub("", page.read_text()))


def test_readme_is_a_front_page_with_the_two_set_up_commands() -> None:
    readme = (REPO / "README.md").read_text()
    assert len(readme.splitlines()) <= 200
    blocks = re.findall(r"```sh\n(.*?)```", readme, re.DOTALL)
    assert blocks[0].strip().endswith(".venv/bin/gx2-gateway --config config/demo.yaml")
    assert blocks[1].strip() == ".venv/bin/python -m pytest"
    assert "\n.venv/bin/python -m pytest\n" in readme  # CI's check, .ci/run


@pytest.mark.parametrize("page", [REPO / "README.md", *PAGES], ids=lambda p: p.name)
def test_every_link_reaches_its_page_and_heading(page: Path) -> None:
    for target in links(page):
        if re.match(r"[a-z]+://|mailto:", target):
            continue
        path, _, anchor = target.partition("#")
        linked = (page.parent / path).resolve() if path else page
        assert linked.is_file(), f"{page.name}: {target}: no such file"
        assert linked.suffix != ".md" or linked.parent in (DOCS, REPO), target
        if anchor:
            assert anchor in anchors(linked), f"{page.name}: {target}: no such heading"


def test_every_page_is_on_the_site_and_the_readme_maps_them() -> None:
    config = yaml.safe_load((REPO / "mkdocs.yml").read_text())
    on_site = {next(iter(item.values())) for item in config["nav"]}
    assert on_site == {page.name for page in PAGES}
    readme_links = {t.partition("#")[0] for t in links(REPO / "README.md")}
    assert {f"docs/{page.name}" for page in PAGES if page.name != "index.md"} \
        <= readme_links


def named_in_the_map() -> dict[str, set[str]]:
    """Directory (from the repository's root) -> the files the map names in it."""
    page = (DOCS / "development.md").read_text()
    block = page.split("## Where things are", 1)[1].split("```\n", 1)[1].split("```", 1)[0]
    named: dict[str, set[str]] = {}
    stack: list[tuple[int, str]] = []  # (indentation, directory)
    for line in block.splitlines():
        indent = len(line) - len(line.lstrip())
        first = line.split()[0] if line.strip() else ""
        if first.endswith("/") and indent < 20:
            while stack and stack[-1][0] >= indent:
                stack.pop()
            parent = stack[-1][1] if stack else ""
            stack.append((indent, parent + first))
            directory = parent + first
        else:
            while stack and stack[-1][0] >= indent and indent < 20:
                stack.pop()
            directory = stack[-1][1] if stack else ""
        for name in re.findall(r"\b[\w]+\.py\b", line):
            named.setdefault(directory, set()).add(name)
    return named


@pytest.mark.parametrize("directory", ["aspp/", "gateway/", "gateway/client/",
                                       "gateway/common/",
                                       "gateway/daemon/", "gateway/daemon/station/",
                                       "gateway/daemon/outputs/", "gateway/ctl/",
                                       "gateway/recording/", "gateway/sim/", "bench/"])
def test_the_map_of_the_tree_names_every_module_and_nothing_gone(directory: str) -> None:
    named = named_in_the_map().get(directory, set())
    there = {p.name for p in (REPO / directory).glob("*.py") if p.name != "__init__.py"}
    assert not there - named, f"{directory}: not in the map: {sorted(there - named)}"
    assert not named - there, f"{directory}: in the map but gone: {sorted(named - there)}"


def test_the_scan_configuration_runs_beside_the_demo() -> None:
    """getting-started's scan.yaml is run while the demo may still run: none of its
    endpoints is one the demo holds (issue 43: it had none of its own, so it took the
    demo's 5555 and 5556)."""
    from gateway.daemon.config import GatewayConfig, load_config
    text = (DOCS / "getting-started.md").read_text()
    block = next(b for b in re.findall(r"```yaml\n(.*?)```", text, re.DOTALL)
                 if "nodes: []" in b)
    scan = GatewayConfig.model_validate(yaml.safe_load(block))
    demo = load_config(REPO / "config" / "demo.yaml")

    def held(config: GatewayConfig) -> set[str]:
        ports = {config.publish.endpoint, config.control.endpoint}
        ports |= {section.endpoint for section in (config.metrics, config.live) if section}
        return {endpoint.rsplit(":", 1)[1] for endpoint in ports}
    assert held(scan) & held(demo) == set()


def test_the_reload_recipe_runs_on_a_pty_not_the_demo() -> None:
    """configuration.md invites a reload: its recipe's gateway opens gx2-sim's pty,
    not ``sim://``, which refuses every node change (issue 43), and the file it
    writes validates, with endpoints the demo does not hold."""
    from gateway.daemon.config import GatewayConfig
    text = (DOCS / "configuration.md").read_text()
    recipe = next(b for b in re.findall(r"```sh\n(.*?)```", text, re.DOTALL)
                  if "reload" in b)
    link = re.search(r"gx2-sim .*--link (\S+)", recipe)
    written = re.search(r"<<'EOF'\n(.*?)^EOF", recipe, re.DOTALL | re.MULTILINE)
    assert link and written, recipe
    config = GatewayConfig.model_validate(yaml.safe_load(written[1]))
    assert [s.port for s in config.stations] == [link[1]]
    assert {config.publish.endpoint, config.control.endpoint}.isdisjoint(
        {"tcp://127.0.0.1:5555", "tcp://127.0.0.1:5556"})


def test_labrecorder_says_liblsls_namespace_warning_is_harmless() -> None:
    """Inside the network namespace labrecorder.md suggests, liblsl warns that it found
    no local network interface: the page quotes the warning as liblsl has it, and says
    it is harmless (issue 43: a user took it for the reason nothing resolved)."""
    pylsl = pytest.importorskip("pylsl")
    library = next(Path(pylsl.__file__).parent.rglob("liblsl*.so*"))
    found = re.search(rb"No local network interface addresses[ -~]*", library.read_bytes())
    assert found, library
    page = " ".join((DOCS / "labrecorder.md").read_text().split())
    assert found[0].decode() in page
    said = page.split(found[0].decode())[1][:200]
    assert "harmless" in said, said
