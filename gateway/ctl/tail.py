"""``gx2ctl tail``: published records as JSON lines, until interrupted."""

from __future__ import annotations

import signal
import sys
import time
from types import FrameType
from typing import TYPE_CHECKING, Any

import zmq

from gateway.common import curve
from gateway.common.endpoints import connectable
from gateway.common.protocol import MAX_REPLY_BYTES, Exit
from gateway.common.topics import PREFIX, STATUS_TOPIC, node_prefix

from . import PROG
from .client import Client, CtlError
from .output import BadMessage, tail_line

if TYPE_CHECKING:
    from .cli import Endpoints




def publish_endpoint(status: dict[str, Any]) -> str:
    """The publish endpoint a status reply names."""
    gateway = status.get("gateway")
    found = gateway.get("publish_endpoint") if isinstance(gateway, dict) else None
    if not isinstance(found, str) or "://" not in found:
        raise CtlError("the gateway's status reply names no gateway.publish_endpoint",
                       Exit.NODE_FAILED)
    return found


class Stop:
    """Set by SIGINT/SIGTERM: tail finishes its batch and exits 0, quietly."""

    requested = False

    def __init__(self) -> None:
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, self._request)

    def _request(self, signum: int, frame: FrameType | None) -> None:
        self.requested = True


HEARTBEATS_MISSED = 3
"""The gateway is taken for dead after this many heartbeats of silence (and at least
``--timeout``): a slow heartbeat never makes a live gateway look dead."""


def run_tail(nodes: list[int], where: Endpoints, timeout: float) -> int:
    """Print published records until a signal; malformed messages are warned about.
    The gateway's heartbeat (gx2/gateway/status, not printed) proves it is alive even
    when no node streams: nothing at all for ``timeout`` seconds (and three heartbeats)
    exits 3. A node the gateway does not have is a usage error (exit 2)."""
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
    unknown = [node for node in nodes if node not in configured]
    if unknown:
        raise CtlError(f"node {unknown[0]} is not configured in this gateway (it has "
                       f"{', '.join(map(str, configured)) or 'none'})", Exit.USAGE)
    silence = max(timeout, HEARTBEATS_MISSED * heartbeat if heartbeat else 0.0)
    address = connectable(found, where.control)
    stop = Stop()
    context = zmq.Context()
    sub = context.socket(zmq.SUB)
    try:
        sub.setsockopt(zmq.LINGER, 0)
        sub.setsockopt(zmq.MAXMSGSIZE, MAX_REPLY_BYTES)  # records are far smaller
        if secured and where.keys is not None:
            curve.connect_as(sub, where.keys)
        try:
            sub.connect(address)
        except zmq.ZMQError as error:
            raise CtlError(f"cannot use publish endpoint {address}: {error}",
                           Exit.USAGE) from None
        prefixes = [node_prefix(node) for node in dict.fromkeys(nodes)] or [PREFIX]
        for prefix in prefixes:
            sub.setsockopt(zmq.SUBSCRIBE, prefix.encode())
        sub.setsockopt(zmq.SUBSCRIBE, STATUS_TOPIC)
        heard = time.monotonic()
        while not stop.requested:
            if sub.poll(100, zmq.POLLIN):
                _print_batch(sub, stop)
                heard = time.monotonic()
            elif time.monotonic() - heard > silence:
                raise CtlError(f"the gateway at {address} published nothing for "
                               f"{silence:g} s (not even its heartbeat)", Exit.NO_ANSWER)
    finally:
        sub.close(linger=0)
        context.term()
    return Exit.OK


def _print_batch(sub: zmq.Socket, stop: Stop) -> None:
    """Every message already queued, printed, then one flush."""
    while not stop.requested:
        try:
            frames = sub.recv_multipart(zmq.NOBLOCK)
        except zmq.Again:
            break
        try:
            line = tail_line(frames, nodes_only=True)
        except BadMessage as problem:
            sys.stdout.flush()
            print(f"{PROG}: skipped a message {problem}", file=sys.stderr, flush=True)
            continue
        if line is not None:
            print(line)
    sys.stdout.flush()
