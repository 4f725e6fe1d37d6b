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
    """Every module a file imports (relative imports resolved from its package)."""
    package = list(path.relative_to(PACKAGE.parent).parent.parts)
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - node.level + 1]
                found.add(".".join(base + ([node.module] if node.module else [])))
            else:
                found.add(node.module or "")
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
