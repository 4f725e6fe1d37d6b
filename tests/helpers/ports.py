"""A free TCP port on the loopback, for an endpoint a test binds."""

from __future__ import annotations

import socket


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def endpoint() -> str:
    """A tcp:// endpoint on the loopback that nothing uses yet."""
    return f"tcp://127.0.0.1:{free_port()}"
