"""What each program imports: gx2ctl no pydantic (every run of it would pay to load it;
only ``--config`` loads the gateway's own validator), the daemon no prometheus-client
unless it serves metrics, and the daemon reaches the simulator only through the module
that opens a port from its URL."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "gateway"


def test_gx2ctl_imports_no_pydantic() -> None:
    code = ("import sys, gateway.ctl.cli, gateway.ctl.tail, gateway.ctl.output; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in "
            "('pydantic', 'pydantic_core', 'yaml')))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60, check=True)
    assert run.stdout.strip() == "[]", run.stdout


def imported_modules(path: Path) -> set[str]:
    """Every module a file imports (relative imports resolved from its package), wherever
    the import is (in a function, under TYPE_CHECKING); ``from package import module``
    names the module too."""
    package = list(path.relative_to(PACKAGE.parent).parent.parts)
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            found.add(module)
            found |= {f"{module}.{alias.name}" for alias in node.names}
    return found


def test_the_daemon_reaches_the_simulator_only_through_ports() -> None:
    reaching = sorted(path.name for path in (PACKAGE / "daemon").rglob("*.py")
                      if any(m.startswith("gateway.sim") for m in imported_modules(path)))
    assert reaching == ["ports.py"]


def test_a_station_never_imports_an_output() -> None:
    """A record's way out of a station is one-way: it hands messages to what it is
    given (station/outlet.py) and knows nothing of what stands behind."""
    importing = sorted(f"{path.name}: {module}"
                       for path in (PACKAGE / "daemon" / "station").glob("*.py")
                       for module in imported_modules(path)
                       if module.startswith("gateway.daemon.outputs"))
    assert importing == []


def test_tail_and_sitestream_do_not_import_each_other() -> None:
    """tail.py runs several gateways through sitestream.py, which once took what it
    needed from tail.py back (in a function: a loop hidden, not removed; issue 43):
    what both need is in subscribing.py, below them."""
    ctl = PACKAGE / "ctl"
    assert "gateway.ctl.tail" not in imported_modules(ctl / "sitestream.py")
    assert not {"gateway.ctl.tail", "gateway.ctl.sitestream"} & imported_modules(
        ctl / "subscribing.py")


def test_the_daemon_loads_prometheus_client_only_for_a_metrics_endpoint() -> None:
    """64 ms and 1.8 MiB a gateway without metrics: configuration, never a default."""
    code = ("import sys, gateway.daemon.cli, gateway.daemon.app, gateway.ctl.top; "
            "print(sorted(m for m in sys.modules if m.startswith('prometheus_client')))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60, check=True)
    assert run.stdout.strip() == "[]", run.stdout


def test_no_runner_imports_its_parser_and_status_not_the_gateway() -> None:
    """A runner takes what it needs from a module below the parser (gateway.ctl.where);
    a status report is built from what it is handed: no import loops."""
    runners = {name: imported_modules(PACKAGE / "ctl" / name)
               for name in ("tail.py", "top.py", "record.py")}
    assert {name: "gateway.ctl.cli" in found for name, found in runners.items()} == \
        dict.fromkeys(runners, False)
    assert "gateway.daemon.app" not in imported_modules(PACKAGE / "daemon" / "status.py")


ROOTS = (PACKAGE, PACKAGE.parent / "aspp")
STILL_LOOPING: set[frozenset[str]] = set()
"""Loops known and not mended yet: none may be added to them (issue 43's three are
mended: the last, tail.py <-> sitestream.py, by ctl/subscribing.py)."""


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_loops() -> set[frozenset[str]]:
    """The modules that import each other round a loop, each loop's set (Tarjan's
    strongly connected components of the import graph). An import inside a function or
    under TYPE_CHECKING counts: it hides a loop, it does not remove it. A module's
    parent packages are not counted as imported by it (Python runs them first: a
    package's ``__init__`` importing its own modules is no loop)."""
    paths = {module_name(path): path for root in ROOTS for path in root.rglob("*.py")}
    graph = {name: sorted(m for m in imported_modules(path) if m in paths and m != name)
             for name, path in paths.items()}
    order: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    loops: set[frozenset[str]] = set()

    def visit(name: str) -> None:
        order[name] = low[name] = len(order)
        stack.append(name)
        for other in graph[name]:
            if other not in order:
                visit(other)
                low[name] = min(low[name], low[other])
            elif other in stack:
                low[name] = min(low[name], order[other])
        if low[name] == order[name]:
            members = set()
            while (member := stack.pop()) != name:
                members.add(member)
            if members:
                loops.add(frozenset({name, *members}))

    for name in graph:
        if name not in order:
            visit(name)
    return loops


def test_no_modules_import_each_other_round_a_loop() -> None:
    """A loop makes an import's order matter (the configuration reaching a station's
    nodes through the replay, back to the configuration; the ops and the modules of
    ops registering themselves), and each was hidden in a function or a TYPE_CHECKING
    block: broken by a module below both (station/replayurl.py, opcontext.py,
    outputs/message.py), never by hiding the import."""
    loops = import_loops()
    assert loops <= STILL_LOOPING, sorted(sorted(loop) for loop in loops - STILL_LOOPING)
