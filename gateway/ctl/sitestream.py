"""What ``tail``, ``top`` and ``record`` share when given several gateways: finding
each one's publish endpoint (side by side: one dead gateway costs ``--timeout`` once;
``tail`` and ``top`` take each as it is found, so a dead one delays none of the
others: :class:`Lookups`), one subscriber to them all, and noticing one falling silent
while the others go on."""

from __future__ import annotations

import contextlib
import queue
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
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
    check_nodes(nodes, found)
    return found


WAKE_S = 0.1
"""How often a wait for the first gateway found looks whether it was stopped."""


class Lookups:
    """Each gateway's publish endpoint looked for side by side, a daemon thread each
    (one still asking a dead gateway never holds the exit up), and taken as it is
    found (issue 43: ``tail`` printed nothing, and ``top`` drew nothing, for
    ``--timeout`` while one gateway was dead). One that cannot be found is ``missing``,
    with why; a usage error (a bad key) ends the run, as a NODE none of the gateways
    has does once each is found or missing."""

    def __init__(self, nodes: Sequence[int], named: Sequence[Gateway],
                 timeout: float) -> None:
        self.nodes = nodes
        self.found: list[tuple[Gateway, Source]] = []
        self.missing: dict[str, str] = {}
        """Name -> why it is left out (it did not answer)."""
        self.pending = [gateway.name for gateway in named]
        """The names of those still looked for."""
        self._results: queue.Queue[tuple[Gateway, Source | CtlError]] = queue.Queue()
        for gateway in named:
            threading.Thread(target=self._look, args=(gateway, timeout), daemon=True,
                             name=f"gx2ctl-find-{gateway.name}").start()

    def _look(self, gateway: Gateway, timeout: float) -> None:
        try:
            result: Source | CtlError = find(gateway.where, timeout)
        except CtlError as error:
            result = error
        except Exception as error:  # (a bug: still said, in one line)
            result = CtlError(f"internal error: {type(error).__name__}: {error}",
                              Exit.NODE_FAILED)
        self._results.put((gateway, result))

    def take(self, wait: float | None = 0.0) -> list[tuple[Gateway, Source]]:
        """The gateways found since the last take, waiting up to ``wait`` s for one to
        be found or given up (None: for as long as that takes)."""
        new = []
        while self.pending:
            try:
                gateway, result = self._results.get(timeout=wait) if (
                    wait is None or wait > 0) else self._results.get_nowait()
            except queue.Empty:
                break
            wait = 0.0  # (then whatever else is done already)
            self.pending.remove(gateway.name)
            if isinstance(result, CtlError):
                if result.status == Exit.USAGE:
                    raise CtlError(f"{gateway.name}: {result}", result.status)
                self.missing[gateway.name] = str(result)
            else:
                new.append((gateway, result))
                self.found.append((gateway, result))
        if not self.pending:
            if not self.found:
                raise CtlError("none of the gateways answered", Exit.NO_ANSWER)
            check_nodes(self.nodes, self.found)
        return new

    def first(self, stopped: Callable[[], bool]) -> list[tuple[Gateway, Source]]:
        """Wait for the first gateway found (CtlError if none is); nothing if
        ``stopped()`` first (a signal)."""
        while not (new := self.take(WAKE_S)):
            if stopped():
                return []
        return new


def add(sub: Subscriber, source: Source) -> None:
    """A gateway found after the others, subscribed to."""
    try:
        sub.add(source.address, source.keys)
    except GatewayError as error:
        raise CtlError(str(error), Exit.USAGE) from None


def left_out(lookups: Lookups, said: set[str]) -> None:
    """A line on stderr for each gateway that could not be found, once."""
    for name, why in lookups.missing.items():
        if name not in said:
            said.add(name)
            print(f"{PROG}: {name} left out: {why}", file=sys.stderr, flush=True)


def check_nodes(nodes: Sequence[int], found: Sequence[tuple[Gateway, Source]]) -> None:
    """A usage error for a NODE none of the gateways found has."""
    have = {node for _, source in found for node in source.nodes}
    unknown = [node for node in nodes if node not in have]
    if unknown:
        listed = "; ".join(f"{g.name} has {', '.join(map(str, s.nodes)) or 'none'}"
                           for g, s in found)
        raise CtlError(f"node {unknown[0]} is configured in none of the gateways "
                       f"({listed})", Exit.USAGE)


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


