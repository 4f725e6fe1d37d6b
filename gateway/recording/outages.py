"""When each base station was down (unplugged, its port lost), as the gateway's status
messages (``gx2/gateway/status``, recorded beside the records) tell it: what a stream
misses across such an outage is no radio's loss (:mod:`.losses`). Pure: no I/O.

The records alone cannot tell an unplug from the radio losing every sample for a
while; the status can. The gateway publishes one the moment a station goes down or
comes back, and one every heartbeat, each with every station's ``state`` and ``since``
(UNIX time it last went up or down, on the clock of the records' ``time``) and each
node's ``station``. An outage is from the ``since`` of a status that shows the station
not up to the ``since`` of the next that shows it up. Where the statuses of an outage
were missed (a subscriber that dropped them), a station seen up again with another
``since`` went down in between: from the last status that showed it up (at the latest)
to its new ``since``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NamedTuple

UP = "up"
"""A station's link state while it is up (docs/interface.md, section 4)."""

Station = str | None
"""A base station's name; None for a gateway whose status has no ``stations``."""


class _Seen(NamedTuple):
    since: float
    """When it last came up."""
    at: float
    """The status that last showed it so."""


class Outages:
    """Every station's outages, from the status messages fed in order."""

    def __init__(self) -> None:
        self._stations: dict[int, Station] = {}
        """Each node's base station."""
        self._spans: dict[Station, list[tuple[float, float]]] = {}
        """Each station's outages over: (went down, came back)."""
        self._down: dict[Station, float] = {}
        """Stations down at the last status: since when."""
        self._up: dict[Station, _Seen] = {}

    def status(self, payload: Mapping[str, Any]) -> None:
        """A status message (anything in it that is not as a status has it is passed
        over: a foreign or damaged one tells nothing)."""
        gateway = payload.get("gateway")
        now = _number(gateway.get("time")) if isinstance(gateway, Mapping) else None
        stations = payload.get("stations")
        several = isinstance(stations, list) and bool(stations)
        links = ([(s.get("name"), s) for s in stations if isinstance(s, Mapping)]
                 if several else [(None, payload.get("link"))])
        for name, link in links:
            if isinstance(link, Mapping) and (name is None or isinstance(name, str)):
                self._link(name, link.get("state"), _number(link.get("since")), now)
        nodes = payload.get("nodes")
        for node in nodes if isinstance(nodes, list) else ():
            if isinstance(node, Mapping) and isinstance(node.get("node"), int):
                station = node.get("station") if several else None
                if station is None or isinstance(station, str):
                    self._stations[node["node"]] = station

    def _link(self, name: Station, state: Any, since: float | None,
              now: float | None) -> None:
        """One station's state in a status made at ``now``."""
        since = since if since is not None else now
        if since is None or not isinstance(state, str):
            return
        if state != UP:
            self._down.setdefault(name, since)
            self._up.pop(name, None)
            return
        down = self._down.pop(name, None)
        seen = self._up.get(name)
        if down is None and seen is not None and seen.since != since:
            down = seen.at  # (down and back between two statuses seen)
        if down is not None:
            self._spans.setdefault(name, []).append((down, since))
        self._up[name] = _Seen(since, now if now is not None else since)

    def back(self, node: int, after: float, at: float) -> float | None:
        """When the node's station came back from the last outage between ``after`` and
        ``at`` (the times of two records of the node), or None if none was. An outage
        not over by the last status seen ends by ``at`` (a record came through)."""
        if node not in self._stations:
            return None
        station = self._stations[node]
        ends = [up for down, up in self._spans.get(station, ()) if down < at and up > after]
        down = self._down.get(station)
        if down is not None and down < at:
            ends.append(at)
        return max(ends, default=None)


def _number(value: Any) -> float | None:
    if isinstance(value, (int, float)) and not isinstance(value, bool) and value == value:
        return float(value)
    return None


__all__ = ["Outages"]
