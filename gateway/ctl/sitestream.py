"""What ``tail``, ``top`` and ``record`` share when given several gateways: finding
each one's publish endpoint (side by side: one dead gateway costs ``--timeout`` once),
one subscriber to them all, and noticing one falling silent while the others go on."""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from gateway.client import GatewayError, Subscriber
from gateway.common.protocol import Exit

from . import PROG
from .client import CtlError
from .subscribing import Source, find, warn_malformed
from .where import Gateway


def sources(nodes: Sequence[int], named: Sequence[Gateway], timeout: float,
            every: bool) -> list[tuple[Gateway, Source]]:
    """Each gateway with where to subscribe to it. One that cannot be found (asked for
    its publish endpoint, it did not answer) ends the run when ``every`` is needed,
    else is left out with a line on stderr (the run ends only when none is left). A
    NODE that none of them has is a usage error."""
    def look(gateway: Gateway) -> Source | CtlError:
        try:
            return find(gateway.where, timeout)
        except CtlError as error:
            return error
    with ThreadPoolExecutor(max_workers=len(named)) as pool:
        looked = list(pool.map(look, named))
    found = []
    for gateway, result in zip(named, looked, strict=True):
        if isinstance(result, CtlError):
            if every or result.status == Exit.USAGE:
                raise CtlError(f"{gateway.name}: {result}", result.status)
            print(f"{PROG}: {gateway.name} left out: {result}", file=sys.stderr, flush=True)
            continue
        found.append((gateway, result))
    if not found:
        raise CtlError("none of the gateways answered", Exit.NO_ANSWER)
    have = {node for _, source in found for node in source.nodes}
    unknown = [node for node in nodes if node not in have]
    if unknown:
        listed = "; ".join(f"{g.name} has {', '.join(map(str, s.nodes)) or 'none'}"
                           for g, s in found)
        raise CtlError(f"node {unknown[0]} is configured in none of the gateways "
                       f"({listed})", Exit.USAGE)
    return found


@contextlib.contextmanager
def subscribe_all(nodes: Sequence[int], found: Sequence[tuple[Gateway, Source]],
                  **options: Any) -> Iterator[Subscriber]:
    """One subscriber to every gateway found, each with its own CURVE keys (or none)."""
    try:
        sub = Subscriber([source.address for _, source in found], nodes,
                         keys={source.address: source.keys for _, source in found},
                         on_malformed=warn_malformed, **options)
    except GatewayError as error:
        raise CtlError(str(error), Exit.USAGE) from None
    with sub:
        yield sub


class Silences:
    """Which gateways have fallen silent (nothing, not even a heartbeat, for their
    silence), said once on stderr as each falls silent and once as it is heard again."""

    def __init__(self, sub: Subscriber, found: Sequence[tuple[Gateway, Source]]) -> None:
        self.sub = sub
        self.found = found
        self.silent: set[str] = set()

    def check(self) -> bool:
        """Look again; True when every gateway is silent."""
        for gateway, source in self.found:
            quiet = self.sub.silent_for(source.address)
            if quiet > source.silence and source.address not in self.silent:
                self.silent.add(source.address)
                print(f"{PROG}: {gateway.name} at {source.address} published nothing for "
                      f"{source.silence:g} s (not even its heartbeat)", file=sys.stderr,
                      flush=True)
            elif quiet <= source.silence and source.address in self.silent:
                self.silent.discard(source.address)
                print(f"{PROG}: {gateway.name} at {source.address} is heard again",
                      file=sys.stderr, flush=True)
        return len(self.silent) == len(self.found)

    def all_silent(self) -> CtlError:
        longest = max(source.silence for _, source in self.found)
        return CtlError(f"none of the gateways published anything for {longest:g} s "
                        "(not even a heartbeat)", Exit.NO_ANSWER)


def names(found: Sequence[tuple[Gateway, Source]]) -> dict[str, str]:
    """Each publish endpoint's gateway's name."""
    return {source.address: gateway.name for gateway, source in found}


def quiet_for(sub: Subscriber) -> float:
    """Seconds since the last of the gateways was heard (every one silent that long)."""
    return min(sub.silent_for(endpoint) for endpoint in sub.endpoints)


