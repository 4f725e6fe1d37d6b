"""A free TCP port on the loopback, for an endpoint a test binds.

The suite runs in several processes at once (pytest-xdist), each starting gateways
that bind the ports it hands them a moment later. A port the kernel picks (bind to
port 0) comes from the ephemeral range, which every outgoing connection draws from
too, and another worker's probe may be given the same one meanwhile. So the ports
come from below the ephemeral range (Linux's begins at 32768), where no connection is
given one, each worker from its own residue class, each process in turn (never the
same port twice in a row), and each is checked free by binding it."""

from __future__ import annotations

import itertools
import os
import random
import re
import socket

LOW, HIGH = 20000, 32768
"""The ports handed out: below Linux's ephemeral range, above the well-known ones."""
STRIPES = 16
"""Residue classes: worker gwN takes the ports whose remainder is N mod STRIPES."""


def _stripe() -> int:
    worker = re.fullmatch(r"gw(\d+)", os.environ.get("PYTEST_XDIST_WORKER", ""))
    return int(worker.group(1)) % STRIPES if worker else 0


def _candidates() -> itertools.cycle[int]:
    ports = list(range(LOW + _stripe(), HIGH, STRIPES))
    start = random.randrange(len(ports))  # (a rerun soon after does not meet the last)
    return itertools.cycle(ports[start:] + ports[:start])


_CANDIDATES = _candidates()


def free_port() -> int:
    for port in _CANDIDATES:
        with socket.socket() as probe:
            try:
                probe.bind(("127.0.0.1", port))
            except OSError:  # (taken, or in TIME_WAIT)
                continue
            return port
    raise AssertionError("unreachable")


def endpoint() -> str:
    """A tcp:// endpoint on the loopback that nothing uses yet."""
    return f"tcp://127.0.0.1:{free_port()}"
