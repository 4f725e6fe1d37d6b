"""gateway.client offline is gateway.client live: what a Subscriber received from the
gateway running on gx2-sim, and what Recording reads back from the files the gateway
recorded meanwhile (rotated), are the same Message and Status objects, field for field
(an Inertia-Link's NaN magnetometer NaN in both)."""

from __future__ import annotations

import math
import time
from pathlib import Path

from gateway.client import Message, Recording, Status, Subscriber
from gateway.sim.node import NodeSettings
from tests.helpers.waiting import wait_for

NODES = [{"address": 76, "stream": "accel_angrate_mag"}, {"address": 77, "stream": "euler"}]


def same(live: Message | Status, recorded: Message | Status) -> bool:
    """Field for field but the source (an endpoint, the recordings' path), the payload
    compared with NaN equal to NaN."""
    def fields(event: Message | Status) -> tuple:
        kept = tuple(getattr(event, name) for name in event.__slots__
                     if name not in ("gateway", "payload", "gap", "restarted"))
        return (*kept, repr(sorted(event.payload.items())))
    return fields(live) == fields(recorded)


def test_a_recording_reads_back_what_the_live_subscriber_received(simulator, gateway,
                                                                  tmp_path: Path) -> None:
    sim = simulator(NodeSettings(76), NodeSettings(77))
    directory = tmp_path / "recordings"
    gw = gateway(sim.path, NODES, record={"directory": str(directory), "rotate_mb": 0.05})
    gw.wait_streaming(76, 77)
    live: list[Message | Status] = []
    with Subscriber(gw.publish_endpoint, nodes=[76], status=True) as sub:
        deadline = time.monotonic() + 30
        while len(list(directory.glob("*.mcap"))) < 2 or sum(
                isinstance(e, Message) for e in live) < 300:
            assert time.monotonic() < deadline, "no rotation, or too few records"
            event = sub.receive(0.05)
            if event is not None:
                live.append(event)
    assert gw.terminate()[0] == 0, gw.log()
    wait_for(lambda: len(list(directory.glob("*.mcap"))) >= 2, 5, "the files")

    with Recording(directory, nodes=[76], status=True) as recording:
        recorded = list(recording)
    assert not recording.reading.partial and recording.duplicates == 0
    by_seq = {e.seq: e for e in recorded if isinstance(e, Message)}
    by_time = {e.payload["gateway"]["time"]: e for e in recorded if isinstance(e, Status)}
    messages = [e for e in live if isinstance(e, Message)]
    statuses = [e for e in live if isinstance(e, Status)]
    assert messages and statuses
    for event in messages:
        assert same(event, by_seq[event.seq]), (event, by_seq[event.seq])
        assert all(math.isnan(v) for v in by_seq[event.seq]["mag"])  # an Inertia-Link's
    for event in statuses:
        assert same(event, by_time[event.payload["gateway"]["time"]])
    # nothing was lost live or in the files: no gap on either side
    assert [m.gap for m in messages] == [by_seq[m.seq].gap for m in messages] == [0] * len(
        messages)
    assert {m.record for m in messages} == {"accel_angrate_mag"}
