"""What ``tail``, ``top`` and ``record`` share: where a gateway publishes and how to
subscribe to it (its publish endpoint, keys, nodes and the silence after which it is
taken for dead, from its configuration or its status reply), and stopping on a
signal. Below :mod:`.tail` and :mod:`.sitestream`, so that neither imports the other
back (issue 43: tail.py and sitestream.py imported each other)."""

from __future__ import annotations

import contextlib
import signal
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from types import FrameType
from typing import TYPE_CHECKING, Any

from gateway.client import GatewayError, Malformed, Subscriber
from gateway.common import curve
from gateway.common.endpoints import connectable
from gateway.common.protocol import Exit

from . import PROG
from .client import Client, CtlError

if TYPE_CHECKING:
    from .where import Endpoints


def publish_endpoint(status: dict[str, Any]) -> str:
    """The publish endpoint a status reply names."""
    gateway = status.get("gateway")
    found = gateway.get("publish_endpoint") if isinstance(gateway, dict) else None
    if not isinstance(found, str) or "://" not in found:
        raise CtlError("the gateway's status reply names no gateway.publish_endpoint",
                       Exit.NODE_FAILED)
    return found


class Stop:
    """Set by SIGINT/SIGTERM: tail, top or record finishes what it is doing and exits
    0, quietly."""

    requested = False

    def __init__(self) -> None:
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, self._request)

    def _request(self, signum: int, frame: FrameType | None) -> None:
        self.requested = True


HEARTBEATS_MISSED = 3
"""The gateway is taken for dead after this many heartbeats of silence (and at least
``--timeout``): a slow heartbeat never makes a live gateway look dead."""


@dataclass(frozen=True)
class Source:
    """A gateway's publish endpoint as a subscriber connects to it."""

    address: str
    keys: curve.ClientKeys | None
    """CURVE keys, if the gateway encrypts what it publishes."""
    silence: float
    """Seconds of silence after which the gateway is taken for dead."""
    nodes: tuple[int, ...] = ()
    """The nodes it has."""


@contextlib.contextmanager
def subscribe(nodes: list[int], where: Endpoints, timeout: float,
              found: Source | None = None, **options: Any
              ) -> Iterator[tuple[Subscriber, float]]:
    """A subscriber to ``nodes`` (all if empty) of the gateway ``where`` names (or
    ``found`` there already), and the silence after which that gateway is taken for
    dead."""
    found = found or source(nodes, where, timeout)
    try:
        sub = Subscriber(found.address, nodes, keys=found.keys, on_malformed=warn_malformed,
                         **options)
    except GatewayError as error:
        raise CtlError(str(error), Exit.USAGE) from None
    with sub:
        yield sub, found.silence


def source(nodes: list[int], where: Endpoints, timeout: float) -> Source:
    """Where to subscribe to the gateway ``where`` names: its publish endpoint, key and
    nodes come from the configuration, or else from its status reply. A node it does
    not have is a usage error."""
    found = find(where, timeout)
    unknown = [node for node in nodes if node not in found.nodes]
    if unknown:
        raise CtlError(f"node {unknown[0]} is not configured in this gateway (it has "
                       f"{', '.join(map(str, found.nodes)) or 'none'})", Exit.USAGE)
    return found


def find(where: Endpoints, timeout: float) -> Source:
    """Where to subscribe to the gateway ``where`` names, and the nodes it has."""
    found, secured = where.publish, where.publish_secured
    heartbeat, configured = where.heartbeat_s, where.nodes
    if found is None or configured is None:
        with Client(where.control, timeout, where.keys) as client:
            status = client.call("status")
        gateway = status.get("gateway") if isinstance(status.get("gateway"), dict) else {}
        found = publish_endpoint(status)
        secured = bool(gateway.get("publish_curve"))
        heartbeat = gateway.get("heartbeat_s") if isinstance(
            gateway.get("heartbeat_s"), (int, float)) else None
        listed = status.get("nodes") if isinstance(status.get("nodes"), list) else []
        configured = tuple(n.get("node") for n in listed if isinstance(n, dict))
    silence = max(timeout, HEARTBEATS_MISSED * heartbeat if heartbeat else 0.0)
    return Source(connectable(found, where.control), where.keys if secured else None,
                  silence, tuple(configured))


def warn_malformed(endpoint: str, problem: Malformed) -> None:
    sys.stdout.flush()
    print(f"{PROG}: skipped a message {problem}", file=sys.stderr, flush=True)
