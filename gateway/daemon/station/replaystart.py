"""Where a replay's ``seq`` and ``device_time`` start: at the recorded ones.

A gateway counts both from its own start: ``seq`` the messages it published for a node,
``device_time`` the node's timer unwrapped across every 218 s wrap it saw. A replay of
the recording's first file counts from that start as the gateway did; a later file (the
ones before it deleted by retention, or copied away alone) begins with a node at seq
3302 and device time 4,000 s, and no read in it tells so: its first timer reading
unwraps to less than 218 s, and its first record is the replay's first.

The file says it all the same: a gateway's recording holds every record it published,
each after the read it was decoded from. So the replay reads each read's records before
playing the read (:class:`~gateway.daemon.station.replay.ReplayLink` looks that far ahead), and
each node's first record published in the replay takes the recorded seq and device time
of the record it is (the same node, record and timer). From there the node counts on as
the recording gateway did: its seq from the recorded one, and its device time by the
same whole number of timer ticks ahead of its own unwrapping (what the node and its
clock estimate work on inside stays as they unwrapped it, so nothing inside jumps).

A node whose first records have no timer, or none recorded, waits for one that matches
(until then it counts from the file's start); only records of nodes still waiting are
kept, at most KEPT of them.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from aspp.timing import TICKS_PER_SECOND
from gateway.recording.files import RecordingError
from gateway.recording.reader import Entry

from .outlet import Publishes

if TYPE_CHECKING:
    from .nodes import Node

KEPT = 100_000
"""Recorded records kept to match against, at most (a node that never matches)."""


class RecordedStart:
    """A replaying station's way to the publisher: each node's records renumbered from
    the recorded ``seq``, and its ``device_time`` carried on from the recorded one."""

    def __init__(self, publisher: Publishes, nodes: Mapping[int, Node]) -> None:
        self._publisher = publisher
        self._nodes = nodes
        self.waiting = set(nodes)
        """Nodes whose first record has not been matched to a recorded one yet."""
        self._recorded: dict[tuple[int, str, int], tuple[int, Any]] = {}
        """(node, record, timer) -> (seq, device_time) recorded."""
        self._ahead: dict[int, int] = {}
        """Timer ticks the recorded device time was ahead of the replay's, by node."""

    def recorded(self, entry: Entry) -> None:
        """A record the recording gateway published (an entry on ``gx2/<node>/...``)."""
        try:
            payload = entry.payload()
        except RecordingError:
            return
        node, timer, seq = payload.get("node"), payload.get("timer"), payload.get("seq")
        if (node in self.waiting and type(timer) is int and type(seq) is int
                and len(self._recorded) < KEPT):
            self._recorded.setdefault((node, str(payload.get("record")), timer),
                                      (seq, payload.get("device_time")))

    def publish(self, node: int, record: str, payload: dict[str, Any]) -> bool:
        if self.waiting and node in self.waiting:
            self._start(node, record, payload)
        ahead = self._ahead.get(node)
        if ahead and "device_time" in payload:
            # (in ticks, as the recording gateway's were counted: the same double)
            payload["device_time"] = (round(payload["device_time"] * TICKS_PER_SECOND)
                                      + ahead) / TICKS_PER_SECOND
        return self._publisher.publish(node, record, payload)

    def _start(self, node: int, record: str, payload: dict[str, Any]) -> None:
        found = self._recorded.get((node, record, payload.get("timer")))  # type: ignore[arg-type]
        if found is None:
            return
        seq, device_time = found
        self._nodes[node].seq += seq - payload["seq"]
        payload["seq"] = seq
        own = payload.get("device_time")
        if isinstance(device_time, (int, float)) and isinstance(own, float):
            self._ahead[node] = round((device_time - own) * TICKS_PER_SECOND)
        self.waiting.discard(node)
        if not self.waiting:
            self._recorded.clear()
