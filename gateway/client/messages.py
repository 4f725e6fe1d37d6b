"""What a subscriber yields, live or from a recording: a :class:`Message` per record,
a :class:`Status` per heartbeat, and the bookkeeping that gives each message its
``gap`` and ``restarted`` (:class:`Numbering`), the same for both."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from gateway.common.jsontext import json_line
from gateway.common.payloads import BOOKKEEPING


class Malformed(Exception):
    """A message that is not ``[topic, msgpack map]`` of the gateway's shape."""


@dataclass(frozen=True, slots=True)
class Message:
    """One record of one node, as its gateway published it."""

    gateway: str
    """The endpoint it came from (read from recordings: the paths given, as given)."""
    node: int
    record: str
    seq: int
    host_time: float
    time: float | None
    """When the node took the sample (UNIX s, host clock); None for an untimed record."""
    device_time: float | None
    lqi: int | None
    rssi: int | None
    payload: Mapping[str, Any] = field(repr=False)
    """Everything published, the record's own fields and the keys above."""
    gap: int = 0
    """Messages of this node that did not reach this subscriber just before this one."""
    restarted: bool = False
    """The first message after the gateway restarted (its ``seq`` began again)."""

    def __getitem__(self, name: str) -> Any:
        return self.payload[name]

    def __contains__(self, name: object) -> bool:
        return name in self.payload

    @property
    def fields(self) -> dict[str, Any]:
        """The record's own fields (``accel``, ``timer``, ...)."""
        return {k: v for k, v in self.payload.items() if k not in BOOKKEEPING}

    def json(self) -> str:
        """The payload as one strict JSON line (NaN as null)."""
        return json_line(self.payload)


@dataclass(frozen=True, slots=True)
class Status:
    """The gateway's heartbeat (``gx2/gateway/status``): the map ``gx2ctl status`` shows."""

    gateway: str
    payload: Mapping[str, Any] = field(repr=False)
    restarted: bool = False
    """The gateway started again since its last status."""

    @property
    def nodes(self) -> list[dict[str, Any]]:
        nodes = self.payload.get("nodes")
        return [n for n in nodes if isinstance(n, dict)] if isinstance(nodes, list) else []


Event = Message | Status


class Numbering:
    """Each gateway's numbering of its nodes' messages, followed: the gap before a
    message (``seq`` steps past +1), a restart (``seq`` goes back, or the heartbeat's
    uptime does), and the totals. Keyed by whatever tells gateways apart (an endpoint)."""

    def __init__(self) -> None:
        self._last_seq: dict[tuple[str, int], int] = {}
        self._uptime: dict[str, float] = {}
        self.lost: dict[tuple[str, int], int] = {}
        """Per (gateway, node): messages that never reached this subscriber."""
        self.restarts: dict[str, int] = {}

    def forget(self) -> None:
        """Start afresh (the totals kept): what comes next follows nothing."""
        self._last_seq.clear()
        self._uptime.clear()

    def count(self, gateway: str, node: int, seq: int) -> tuple[int, bool]:
        """(gap, restarted) of a message numbered ``seq``."""
        key = (gateway, node)
        last = self._last_seq.get(key)
        self._last_seq[key] = seq
        if last is None:
            return 0, False
        if seq <= last:  # the gateway's numbering began again
            return 0, True
        gap = seq - last - 1
        if gap:
            self.lost[key] = self.lost.get(key, 0) + gap
        return gap, False

    def started(self, gateway: str, payload: Mapping[str, Any]) -> bool:
        """Whether this status is the first since the gateway started again: its uptime
        went back (a step of the host clock moves neither)."""
        state = payload.get("gateway")
        uptime = number(state.get("uptime")) if isinstance(state, dict) else None
        if uptime is None:
            return False
        before = self._uptime.get(gateway)
        self._uptime[gateway] = uptime
        if before is not None and uptime < before:
            self.restarts[gateway] = self.restarts.get(gateway, 0) + 1
            return True
        return False

    def message(self, gateway: str, node: int, record: str, payload: Mapping[str, Any],
                topic: str, wanted: bool = True) -> Message | None:
        """The Message of a record's payload, counted (None if not ``wanted``: a record
        filtered out still takes its ``seq``, so it is never taken for a gap);
        Malformed if it has no ``seq``."""
        seq = seq_of(payload, topic)
        gap, restarted = self.count(gateway, node, seq)
        if not wanted:
            return None
        return Message(gateway, node, record, seq, number(payload.get("host_time")) or 0.0,
                       number(payload.get("time")), number(payload.get("device_time")),
                       integer(payload.get("lqi")), integer(payload.get("rssi")),
                       payload, gap, restarted)


def seq_of(payload: Mapping[str, Any], topic: str) -> int:
    """A record's ``seq``; Malformed if it has no integer one."""
    seq = payload.get("seq")
    if not isinstance(seq, int) or isinstance(seq, bool):
        raise Malformed(f"on {topic}: no integer seq")
    return seq


def number(value: Any) -> float | None:
    return float(value) if isinstance(value, (int, float)) and not isinstance(
        value, bool) else None


def integer(value: Any) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) else None
