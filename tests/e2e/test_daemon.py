"""The daemon through a real pty and real sockets: what subscribers receive (CONTRACT
section 4), and that nothing valid is lost on the way."""

from __future__ import annotations

import threading
import time
from itertools import pairwise

import msgpack
import pytest

from aspp.timing import TICKS_PER_SECOND
from gateway.sim.base_station import LineFaults
from gateway.sim.node import GX2, NodeSettings
from tests.helpers.gateway import Control, is_nan
from tests.helpers.processes import STARTUP
from tests.helpers.waiting import wait_for

COMMON = {"node": int, "record": str, "command": int, "seq": int, "host_time": float,
          "lqi": int, "rssi": int}


def quiet_all(sim, gw, *nodes: int) -> None:
    """Stop the simulated streams at the source, so the counts stop moving."""
    for address in nodes:
        sim.call(lambda station, now, a=address: setattr(station.nodes[a], "continuous", 0))


def assert_every_packet_published(sim, gw, *nodes: int) -> None:
    """The gateway published exactly what the base station sent, per node: waited for
    (reading the last bytes may take a moment on a loaded machine), never approximated
    (a lost packet never catches up, so the wait fails at its deadline)."""
    def counts() -> dict[int, tuple[int, int]]:
        sent = sim.station.stats.packets_sent
        return {s["node"]: (s["published"], sent.get(s["node"], 0))
                for s in gw.status()["nodes"] if s["node"] in nodes}
    try:
        wait_for(lambda: all(p == s for p, s in counts().values()), 10,
                 "published == sent")
    except AssertionError:
        raise AssertionError(f"(published, sent) per node: {counts()}") from None
    assert sim.dropped_bytes == 0
    assert all(s["lost_gateway"] == 0 for s in gw.status()["nodes"])


def assert_contiguous(records: list[dict]) -> None:
    seqs = [r["seq"] for r in records]
    assert seqs, "no records"
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), "a gap in seq"


def test_payload_has_every_contract_field(simulator, gateway):
    sim = simulator(NodeSettings(76, model=GX2), NodeSettings(77))
    gw = gateway(sim.path, [{"address": 76, "stream": "accel_angrate_mag_orientation"},
                            {"address": 77, "stream": "accel_angrate_mag"}])
    sub = gw.subscribe("gx2/76/", "gx2/77/")
    streams = {"gx2/76/accel_angrate_mag_orientation", "gx2/77/accel_angrate_mag"}
    messages = sub.until(lambda m: streams <= {t for t, _ in m} and len(m) > 20, 10,
                         "records from both streams")
    for topic, payload in messages:
        node, record = payload["node"], payload["record"]
        assert topic == f"gx2/{node}/{record}"
        for field, kind in COMMON.items():
            assert isinstance(payload[field], kind), (field, payload)
        # timed records carry device_time; untimed ones (the 0xE5 the gateway reads at
        # start-up is published too) do not
        assert isinstance(payload.get("device_time"), float) == ("timer" in payload), payload
        assert payload["rssi"] < 0 and 0 <= payload["lqi"] <= 255
        if "accel" in payload:  # the stream's records; the 0xC4 echo is published too
            assert len(payload["accel"]) == 3
            assert all(isinstance(v, float) for v in payload["accel"])
        assert abs(payload["host_time"] - time.time()) < 60
        if record == "accel_angrate_mag_orientation":
            assert [len(row) for row in payload["orientation"]] == [3, 3, 3]
            assert payload["command"] == 0xCC
    assert {p["record"] for _, p in messages} >= {"accel_angrate_mag_orientation",
                                                   "accel_angrate_mag"}
    inertia_link = [p for _, p in messages if p["node"] == 77 and "mag" in p]
    assert inertia_link and all(is_nan(v) for p in inertia_link for v in p["mag"])
    gx2 = [p for _, p in messages if p["node"] == 76 and "mag" in p]
    assert gx2 and not any(is_nan(v) for p in gx2 for v in p["mag"])


def test_topic_prefix_isolation(simulator, gateway):
    """A subscriber to gx2/76/ gets every record of node 76 and none of node 760."""
    sim = simulator(NodeSettings(76), NodeSettings(760))
    gw = gateway(sim.path, [{"address": 76, "stream": "euler"},
                            {"address": 760, "stream": "euler"}])
    only_76 = gw.subscribe("gx2/76/")
    everything = gw.subscribe("gx2/")
    everything.until(lambda m: {p["node"] for _, p in m if "node" in p} >= {76, 760}, 10,
                     "both nodes")
    only_76.drain(0.5)
    assert only_76.messages and {p["node"] for _, p in only_76.messages} == {76}
    assert all(t.startswith("gx2/76/") for t, _ in only_76.messages)


def test_device_time_across_a_timer_wrap(simulator, gateway, tmp_path):
    """The timer wraps 2^32 ticks (218.45 s) after power-up; device_time never goes back.

    The gateway runs first and the base station is plugged in afterwards, so the wrap,
    3 s after power-up, cannot pass before the gateway is there to see it however long
    the gateway takes to start."""
    gw = gateway(str(tmp_path / "gx2"), [{"address": 76, "stream": "accel_angrate"}],
                 wait=False)
    wait_for(lambda: gw.control.try_call("status", timeout=0.5), STARTUP, "the control socket")
    sub = gw.subscribe("gx2/76/accel_angrate")
    simulator(NodeSettings(76, timer_start=215.5))  # plugged in; wraps 3 s from now
    wrapped_at = 5 * TICKS_PER_SECOND
    records = sub.until(lambda m: any(p["timer"] < wrapped_at for _, p in m[5:])
                        and m[0][1]["timer"] > wrapped_at and len(m) > 60, 15,
                        "the timer to wrap")
    records = [p for _, p in records]
    timers = [p["timer"] for p in records]
    assert any(b < a for a, b in pairwise(timers)), "the raw timer wrapped"
    times = [p["device_time"] for p in records]
    steps = [b - a for a, b in pairwise(times)]
    assert all(step > 0 for step in steps)
    assert max(steps) < 0.1  # 100 Hz, a few lost at most
    assert times[-1] > 218.45


def test_streams_polls_and_pings_interleaved_lose_nothing(simulator, gateway, zmq_context):
    """Three nodes streaming while polls and pings run from two clients at once: every
    packet the base station sent is published, with no gap in any node's seq."""
    sim = simulator(NodeSettings(76), NodeSettings(77), NodeSettings(78), NodeSettings(79))
    gw = gateway(sim.path, [{"address": 76, "stream": "accel_angrate"},
                            {"address": 77, "stream": "euler"},
                            {"address": 78, "stream": "mag"}, {"address": 79}])
    gw.wait_streaming(76, 77, 78)
    sub = gw.subscribe("gx2/")
    sub.until(lambda m: len(m) > 50, 10, "records")
    failures: list[object] = []

    def client(ops: list[tuple[str, dict]]) -> None:
        control = Control(zmq_context, gw.control_endpoint)
        for op, fields in ops:
            reply = control.call(op, **fields)
            if not reply["ok"]:
                failures.append(reply)
        control.socket.close()

    polls = [("poll", {"node": 79, "record": r}) for r in ("euler", "mag", "temperatures")] * 4
    pings = [("ping", {"nodes": [76, 77, 78, 79]})] * 6
    threads = [threading.Thread(target=client, args=(ops,)) for ops in (polls, pings)]
    for thread in threads:
        thread.start()
    sub.drain(0.5)
    for thread in threads:
        thread.join(30)
    assert failures == []
    quiet_all(sim, gw, 76, 77, 78)
    sub.drain(0.3)
    assert_every_packet_published(sim, gw, 76, 77, 78, 79)
    for node in (76, 77, 78):
        assert_contiguous(sub.records(node))
    polled = [p for p in sub.records(79)]
    # every poll's reply was published too (and, on a loaded machine, the second reply
    # to a poll whose first came too late: all published, as assert_every_packet_published
    # above checked against what the base station sent)
    assert len(polled) >= 12


@pytest.mark.parametrize("faults", [
    LineFaults(glue_ack=True), LineFaults(garbage=0.2), LineFaults(false_header=0.2),
], ids=["glued-ack", "garbage", "false-headers"])
def test_line_faults_cost_no_valid_packet(simulator, gateway, faults):
    sim = simulator(NodeSettings(76), NodeSettings(77), line=faults)
    gw = gateway(sim.path, [{"address": 76, "stream": "accel_angrate"},
                            {"address": 77}])
    gw.wait_streaming(76)
    for _ in range(5):
        assert gw.control.call("poll", node=77, record="euler")["ok"]
    if faults.garbage or faults.false_header:  # the test means nothing without faults
        wait_for(lambda: sim.call(lambda station, now: station.stats.faults_injected) >= 10,
                 10, "ten faults on the line")
    quiet_all(sim, gw, 76)
    assert_every_packet_published(sim, gw, 76, 77)
    if faults.garbage or faults.false_header:
        assert gw.status()["link"]["discarded_bytes"] > 0


def test_heartbeat_status_topic(simulator, gateway):
    sim = simulator(NodeSettings(76))
    gw = gateway(sim.path, [{"address": 76, "stream": "euler"}])
    sub = gw.subscribe("gx2/gateway/")
    start = time.monotonic()
    beats = sub.until(lambda m: len(m) >= 2, 5, "two heartbeats")
    assert 0.5 < time.monotonic() - start < 4
    topic, status = beats[-1]
    assert topic == "gx2/gateway/status"
    assert status["link"]["state"] == "up"
    assert [n["node"] for n in status["nodes"]] == [76]


MALFORMED = [
    (b"", b"\xc1"),                                   # not msgpack
    (b"", msgpack.packb([1, 2, 3])),                  # not a map
    (b"", msgpack.packb({"op": "status"})),            # no id
    (b"", msgpack.packb({"id": 1, "op": "explode"})),  # unknown op
    (b"", msgpack.packb({"id": 2, "op": "poll", "node": "76", "record": "euler"})),
    (b"", msgpack.packb({"id": 3, "op": "poll", "node": 76, "record": "eeprom_write"})),
    (b"", msgpack.packb({"id": 4, "op": "ping", "nodes": []})),
    (b"", msgpack.packb({"id": 5, "op": "status", "extra": True})),
    (b"", msgpack.packb({"id": 6, "op": "rate", "node": 76, "hz": -1})),
    (b"", msgpack.packb({"id": 7, "op": "stop", "node": 99})),  # not configured
    (b"", b"\x00" * 5000),                            # over the size limit
]


def test_malformed_control_messages_are_answered_while_streaming(simulator, gateway):
    sim = simulator(NodeSettings(76))
    gw = gateway(sim.path, [{"address": 76, "stream": "accel_angrate"}])
    gw.wait_streaming(76)
    sub = gw.subscribe("gx2/76/")
    sub.until(lambda m: len(m) > 10, 5, "records")
    for frames in MALFORMED:
        gw.control.send_raw(*frames)
        reply = gw.control.receive(5)
        assert reply is not None and reply["ok"] is False, frames
        assert reply["error"]["kind"] == "invalid" and "\n" not in reply["error"]["message"]
    gw.control.send_raw(b"a", b"b", b"c", b"d")   # cannot be a request: dropped
    assert gw.control.call("status")["ok"]        # still serving
    sub.drain(0.3)
    assert_contiguous(sub.records(76))
    assert gw.proc.poll() is None
