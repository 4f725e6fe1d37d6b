"""A free TCP port on the loopback, for an endpoint a test binds."""

from __future__ import annotations

import socket

_GIVEN: set[int] = set()
"""Ports handed out in this process."""


def free_port() -> int:
    """A port nothing is bound to now, never one handed out before in this process: the
    kernel may give a port it has just given again, and a configuration's publish and
    control endpoints were once the same (its check refused it)."""
    while True:
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            port = probe.getsockname()[1]
        if port not in _GIVEN:
            _GIVEN.add(port)
            return port


def endpoint() -> str:
    """A tcp:// endpoint on the loopback that nothing uses yet."""
    return f"tcp://127.0.0.1:{free_port()}"
