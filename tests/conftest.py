"""Fixtures shared by the suite: a ZeroMQ context, gx2-sim on a pty, and the installed
gx2-gateway running on it (tests/helpers has the helpers behind them)."""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import zmq
from hypothesis import settings

from gateway.sim.base_station import LineFaults, RadioLink
from gateway.sim.node import NodeSettings
from gateway.sim.server import Simulator
from tests.helpers.gateway import RunningGateway, gateway_config
from tests.helpers.processes import PROGRAMS, STARTUP, can_favour, favoured, restore_sigint
from tests.helpers.waiting import wait_for

# GNU readline, which pytest imports (for pdb), exports the size of the terminal pytest
# runs in (80x24 without one) as COLUMNS and LINES to every child process, past
# os.environ; gx2ctl would fit its tables to that. A child gets a width only where its
# test gives one.
os.unsetenv("COLUMNS")
os.unsetenv("LINES")

restore_sigint()

# No deadline on a property's examples: at 6 processes on 2 cores an example may wait
# for the CPU longer than hypothesis's 200 ms, and a slow example is no failure here
# (what must be fast is measured by bench/, side by side).
settings.register_profile("suite", deadline=None)
settings.load_profile("suite")

TESTS = Path(__file__).resolve().parent
SHARED_FIXTURE = re.compile(r"scope=[\"'](?:class|module|package|session)[\"']")
"""A fixture made once for several tests of its module."""


FIRST = ("tests/e2e/test_fault_soak.py",)
"""Modules that take minutes of wall time and little CPU: run first, beside the rest,
so the suite does not wait for them at its end."""


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """FIRST's modules at the front (xdist hands out work in this order)."""
    def first(item: pytest.Item) -> bool:
        return item.nodeid.split("::", 1)[0] not in FIRST
    items.sort(key=first)  # (stable: the rest keep their order)


@pytest.hookimpl(optionalhook=True)  # (the suite runs without xdist too: -p no:xdist)
def pytest_xdist_make_scheduler(config: pytest.Config, log: Any) -> Any:
    """The suite runs in several processes (pyproject.toml's addopts, pytest-xdist), each
    test handed to whichever process is free. A module whose tests share a fixture of
    wider scope than a test (the fault soak's run, a wheel built once, a batch of
    programs started at once) goes to one process whole, so that the fixture is made
    once, not once in each process. (What xdist's own ``loadgroup`` mode does with a
    mark, done here by module: that mode marks node ids in a way pytest 9.2 ignores.)"""
    from xdist.scheduler import LoadScopeScheduling

    shared = {path.relative_to(config.rootpath).as_posix()
              for path in TESTS.rglob("test_*.py")
              if SHARED_FIXTURE.search(path.read_text(encoding="utf-8"))}

    class Scheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split("::", 1)[0]
            return module if module in shared else nodeid

    return Scheduling(config, log)


def pytest_report_header(config: pytest.Config) -> str | None:
    """Said at the top of a run whose timing tests cannot run favoured."""
    if can_favour():
        return None
    return ("the timing tests cannot run at a favoured niceness here (not root): beside "
            "the suite's other processes they may fail for want of CPU (-n 2 gives them room)")


@pytest.fixture
def favoured_host() -> Iterator[None]:
    """The test's simulator and gateway at a favoured niceness (processes.favoured)."""
    with favoured():
        yield


COMPUTING = ("tests/aspp/", "tests/recording/")
"""Where the tests compute and wait on nothing (properties, sweeps in simulated time,
recordings read and written): they run at the usual niceness, below the rest."""


@pytest.fixture(autouse=True)
def programs_favoured(request: pytest.FixtureRequest) -> Iterator[None]:
    """Every test that waits on time (its programs, an in-process gateway's deadlines)
    at PROGRAMS niceness, above COMPUTING's; one that asks for ``favoured_host`` (a
    timing test) gets that, higher still. (A module-scoped fixture's programs start
    before this applies, at the usual niceness.)"""
    where = request.node.nodeid
    if "favoured_host" in request.fixturenames or where.startswith(COMPUTING):
        yield
        return
    with favoured(PROGRAMS):
        yield


@pytest.fixture
def zmq_context() -> Iterator[zmq.Context]:
    context = zmq.Context()
    yield context
    context.destroy(linger=0)


@pytest.fixture
def simulator(tmp_path: Path) -> Iterator[Callable[..., Simulator]]:
    """``simulator(NodeSettings(76, ...), ..., radio=..., line=...)``: started, on a pty
    behind ``tmp_path/gx2`` (``name=`` another, for a second base station); stopped (and
    checked for loop errors) afterwards."""
    started: list[Simulator] = []

    def start(*nodes: NodeSettings, radio: dict[int, RadioLink] | None = None,
              line: LineFaults | None = None, name: str = "gx2", **options: Any) -> Simulator:
        sim = Simulator(list(nodes), link=tmp_path / name, radio=radio, line=line,
                        **options).start()
        started.append(sim)
        return sim

    yield start
    for sim in started:
        sim.stop()
        assert sim.error is None, sim.error


@pytest.fixture
def gateway(tmp_path: Path, zmq_context: zmq.Context) -> Iterator[Callable[..., RunningGateway]]:
    """``gateway(port, nodes, **sections)``: gx2-gateway running on that port, ready
    (its control endpoint answers and the base station is open; ``gateway(None, [],
    base_stations=[...])`` several, each open); ``wait=False`` returns
    at once, ``env`` replaces its environment, ``preexec`` runs in the child before it
    starts (resource limits), ``directory`` holds its configuration and log (default
    ``tmp_path``: give each of several gateways its own)."""
    started: list[RunningGateway] = []

    def start(port: str | None, nodes: list[dict[str, Any]], *, wait: bool = True,
              env: dict[str, str] | None = None, preexec: Callable[[], None] | None = None,
              directory: Path | None = None, **sections: Any) -> RunningGateway:
        if directory is not None:
            directory.mkdir(parents=True, exist_ok=True)
        running = RunningGateway(gateway_config(port, nodes, **sections),
                                 directory or tmp_path, zmq_context, env, preexec)
        started.append(running)
        if not wait:
            return running

        def link_up() -> bool:
            if running.proc.poll() is not None:
                raise AssertionError(f"gateway exited {running.proc.returncode}:\n"
                                     f"{running.log()}")
            reply = running.control.try_call("status", timeout=0.5)
            if not (reply and reply["ok"]):
                return False
            result = reply["result"]
            return all(link["state"] == "up" for link in result.get("stations", [])
                       or [result["link"]])
        wait_for(link_up, STARTUP, "the gateway to answer with its link up")
        return running

    yield start
    for running in started:
        running.close()

