"""A replay's seq and device time started at the recorded ones (pure: recorded entries
and published payloads given by hand)."""

from __future__ import annotations

import json
from typing import Any

from aspp.timing import TICKS_PER_SECOND, WRAP_SECONDS
from gateway.daemon.config import NodeEntry
from gateway.daemon.station.nodes import Node
from gateway.daemon.station.replaystart import RecordedStart
from gateway.recording.reader import Entry


class Sink:
    def __init__(self) -> None:
        self.seqs: list[tuple[int, int]] = []
        self.device_times: list[float] = []

    def publish(self, node: int, record: str, payload: dict[str, Any]) -> bool:
        self.seqs.append((node, payload["seq"]))
        self.device_times.append(payload["device_time"])
        return True


def entry(node: int, seq: int, timer: int | None, wraps: int = 0) -> Entry:
    payload = {"node": node, "record": "accel_angrate", "seq": seq, "timer": timer,
               "device_time": ((timer or 0) + wraps * 2**32) / TICKS_PER_SECOND}
    return Entry(f"gx2/{node}/accel_angrate", 0, 0, json.dumps(payload).encode())


def replayed(seq: RecordedStart, nodes: dict[int, Node], node: int, timer: int) -> None:
    """A record the replay decoded: counted by its node, then published (its device
    time the timer's, as a replay's first wrap unwraps it)."""
    nodes[node].seq += 1
    seq.publish(node, "accel_angrate", {"seq": nodes[node].seq, "timer": timer,
                                        "device_time": timer / TICKS_PER_SECOND})


def test_each_node_counts_on_from_the_recorded_seq_of_its_first_record_matched() -> None:
    nodes = {76: Node(NodeEntry(address=76)), 77: Node(NodeEntry(address=77))}
    sink = Sink()
    seq = RecordedStart(sink, nodes)
    # the file begins mid-packet: node 76's record 3302 was decoded from a read the
    # file does not hold, and the replay never decodes it
    for recorded in (entry(76, 3302, 100), entry(76, 3303, 612), entry(77, 3290, 50)):
        seq.recorded(recorded)
    seq.recorded(entry(77, 1, None))  # (untimed: nothing to match by)
    replayed(seq, nodes, 76, 612)
    replayed(seq, nodes, 77, 50)
    replayed(seq, nodes, 76, 1124)
    replayed(seq, nodes, 77, 562)
    assert sink.seqs == [(76, 3303), (77, 3290), (76, 3304), (77, 3291)]
    assert nodes[76].seq == 3304 and nodes[77].seq == 3291  # (status says the same)
    assert not seq.waiting


def test_a_node_without_a_match_counts_from_one_until_one_matches() -> None:
    nodes = {76: Node(NodeEntry(address=76))}
    sink = Sink()
    seq = RecordedStart(sink, nodes)
    replayed(seq, nodes, 76, 100)  # (its record was not recorded)
    seq.recorded(entry(76, 41, 612))
    replayed(seq, nodes, 76, 612)
    replayed(seq, nodes, 76, 1124)
    assert sink.seqs == [(76, 1), (76, 41), (76, 42)]


def test_the_device_time_goes_on_from_the_recorded_wraps_to_the_same_double() -> None:
    nodes = {76: Node(NodeEntry(address=76))}
    sink = Sink()
    seq = RecordedStart(sink, nodes)
    timers = [4_000_000_000 + 393_216 * i for i in range(3)]
    for index, timer in enumerate(timers):
        seq.recorded(entry(76, 500 + index, timer, wraps=17))
    for timer in timers:
        replayed(seq, nodes, 76, timer)
    assert sink.device_times == [(timer + 17 * 2**32) / TICKS_PER_SECOND for timer in timers]
    assert 17 * WRAP_SECONDS < sink.device_times[0] < 18 * WRAP_SECONDS
