"""What the hand-run scripts in bench/ share: the test suite's helpers (a free port),
a process's RSS, and a tap on what the simulator really writes into its pty."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:  # (run as bench/NAME.py: the suite's helpers live there)
    sys.path.insert(0, str(REPO))

from aspp import Decoder, Reply  # noqa: E402
from gateway.sim.server import Simulator  # noqa: E402
from tests.helpers.ports import free_port  # noqa: E402

__all__ = ["REPO", "cpu_ns", "free_port", "rss_kib", "tap_writes"]


def cpu_ns(pid: int) -> int:
    """CPU time of every thread of ``pid`` (ZeroMQ's I/O thread included), in ns."""
    return sum(int((task / "schedstat").read_text().split()[0])
               for task in Path(f"/proc/{pid}/task").iterdir())


def rss_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError(f"no VmRSS for process {pid}")


def tap_writes(sim: Simulator, on_reply: Callable[[Reply, float], None]) -> None:
    """Call ``on_reply(reply, time.monotonic())`` for every reply packet the simulator
    writes into the pty, as it writes it (in the simulator's thread)."""
    decoder = Decoder()
    write = sim.port.write

    def tapped(data: bytes) -> int:
        written = write(data)
        now = time.monotonic()
        for event in decoder.feed(data[:written]):
            if type(event) is Reply:
                on_reply(event, now)
        return written
    sim.port.write = tapped  # type: ignore[method-assign]
