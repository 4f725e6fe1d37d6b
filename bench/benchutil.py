"""What the hand-run scripts in bench/ share: a free port, a process's RSS, and a tap on
what the simulator really writes into its pty."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable
from pathlib import Path

from aspp import Decoder, Reply
from gateway.sim.server import Simulator


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


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
