"""``gx2ctl tail``: published records as JSON lines, until interrupted, from one
gateway or several (each line then says which)."""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING

from gateway.common.jsontext import json_line
from gateway.common.protocol import Exit

from .client import CtlError
from .sitestream import Lookups, Silences, add, left_out, names, subscribe_all
from .subscribing import Stop, subscribe

if TYPE_CHECKING:
    from .where import Endpoints, Gateway


def run_tail(nodes: list[int], where: Endpoints, timeout: float) -> int:
    """Print published records until a signal; malformed messages are warned about.
    The gateway's heartbeat (gx2/gateway/status, not printed) proves it is alive even
    when no node streams: nothing at all for ``timeout`` seconds (and three heartbeats)
    exits 3. A node the gateway does not have is a usage error (exit 2)."""
    stop = Stop()
    with subscribe(nodes, where, timeout) as (sub, silence):
        flushed = time.monotonic()
        while not stop.requested:
            message = sub.receive(FLUSH_S)
            now = time.monotonic()
            if message is not None:
                print(message.json())  # type: ignore[union-attr]
            if message is None or now - flushed >= FLUSH_S:
                sys.stdout.flush()
                flushed = now
            if message is None and sub.silent_for() > silence:
                raise CtlError(f"the gateway at {sub.endpoints[0]} published nothing for "
                               f"{silence:g} s (not even its heartbeat)", Exit.NO_ANSWER)
    sys.stdout.flush()
    return Exit.OK


def run_tail_several(nodes: list[int], named: Sequence[Gateway], timeout: float) -> int:
    """Print the records of several gateways, each line with the ``gateway`` it came
    from (its name), from the first found on: one found later is subscribed to then,
    and one that cannot be found is said on stderr (issue 43: a dead one held every
    line back for ``--timeout``). One that falls silent is said on stderr and the
    others go on; exit 3 only once all are silent (or none could be found)."""
    stop = Stop()
    lookups = Lookups(nodes, named, timeout)
    first = lookups.first(lambda: stop.requested)
    if not first:
        return Exit.OK
    said: set[str] = set()
    called = names(first)
    with subscribe_all(nodes, first) as sub:
        silences = Silences(sub, lookups.found)
        flushed = time.monotonic()
        while not stop.requested:
            message = sub.receive(FLUSH_S)
            now = time.monotonic()
            if message is not None:
                print(json_line({**message.payload,  # type: ignore[union-attr]
                                 "gateway": called[message.gateway]}))
            if message is None or now - flushed >= FLUSH_S:
                sys.stdout.flush()
                flushed = now
                for gateway, source in lookups.take() if lookups.pending else ():
                    add(sub, source)
                    called[source.address] = gateway.name
                left_out(lookups, said)
                # (looked at on each flush: another gateway's records never hide one
                # falling silent)
                if silences.check():
                    raise silences.all_silent()
    sys.stdout.flush()
    return Exit.OK


FLUSH_S = 0.1
"""Printed lines reach a pipe at least this often."""
