"""The subscriber library (gateway.client) against real PUB sockets on the loopback,
publishing what a gateway publishes (and what it should not)."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path

import msgpack
import pytest
import zmq

from gateway.client import GatewayError, Malformed, Message, Status, Subscriber
from gateway.common import curve
from tests.helpers.ports import endpoint
from tests.helpers.waiting import wait_for

NAN = float("nan")


class Gateway:
    """A PUB socket publishing records and heartbeats the way gx2-gateway does."""

    def __init__(self, context: zmq.Context, server: curve.KeyPair | None = None) -> None:
        self.endpoint = endpoint()
        self.socket = context.socket(zmq.PUB)
        self.socket.setsockopt(zmq.LINGER, 0)
        if server is not None:
            curve.serve(self.socket, server)
        self.socket.bind(self.endpoint)
        self.seq: dict[int, int] = {}
        self.started = time.time()

    def record(self, node: int, name: str = "accel_angrate", skip: int = 0,
               **fields: object) -> None:
        seq = self.seq[node] = self.seq.get(node, 0) + 1 + skip
        payload = {"accel": [0.0, 0.1, -1.0], "mag": [NAN, NAN, NAN], "timer": seq * 100,
                   "node": node, "record": name, "command": 0xC2, "seq": seq,
                   "host_time": 1.7e9 + seq, "time": 1.7e9 + seq - 0.01,
                   "device_time": seq / 100, "lqi": 250, "rssi": -50, **fields}
        self.socket.send_multipart([f"gx2/{node}/{name}".encode(), msgpack.packb(payload)])

    def status(self) -> None:
        now = time.time()
        self.socket.send_multipart([b"gx2/gateway/status", msgpack.packb(
            {"gateway": {"time": now, "uptime": now - self.started}, "nodes": [{"node": 76}]})])

    def restart(self) -> None:
        self.seq.clear()
        self.started = time.time()


@pytest.fixture
def context() -> Iterator[zmq.Context]:
    context = zmq.Context()
    yield context
    context.destroy(linger=0)


def connected(sub: Subscriber, *gateways: Gateway) -> None:
    """Publish heartbeats until every gateway's reaches ``sub`` (ZeroMQ's late joiner)."""
    deadline = time.monotonic() + 10
    while any(g.endpoint not in sub.heard for g in gateways):
        assert time.monotonic() < deadline, "the subscriber never connected"
        for g in gateways:
            g.status()
        sub.receive(0.05)


def take(sub: Subscriber, count: int, timeout: float = 5.0) -> list[Message | Status]:
    got: list[Message | Status] = []
    deadline = time.monotonic() + timeout
    while len(got) < count and time.monotonic() < deadline:
        event = sub.receive(0.05)
        if event is not None:
            got.append(event)
    return got


def test_filters_by_node_and_record_and_gives_typed_fields_with_nan_kept(context):
    gw = Gateway(context)
    with Subscriber(gw.endpoint, nodes=[76], records=["accel_angrate"]) as sub:
        connected(sub, gw)
        gw.record(760)                       # another node, whose topic 76 is a prefix of
        gw.record(76, "euler", roll=0.5)     # another record of the node asked for
        gw.record(76)
        [message] = take(sub, 1)
        assert take(sub, 1, timeout=0.3) == []
    assert isinstance(message, Message)
    assert (message.node, message.record, message.seq) == (76, "accel_angrate", 2)
    assert message["accel"] == [0.0, 0.1, -1.0] and "accel" in message.fields
    assert "seq" not in message.fields
    assert message.time == 1.7e9 + 2 - 0.01 and message.device_time == 0.02
    assert (message.lqi, message.rssi) == (250, -50)
    assert all(math.isnan(v) for v in message["mag"])
    assert '"mag": [null, null, null]' in message.json()
    assert message.gap == 0, "a record of another kind was taken for a gap"


def test_counts_seq_gaps_per_node_and_notices_a_restart(context):
    gw = Gateway(context)
    with Subscriber(gw.endpoint, status=True) as sub:
        connected(sub, gw)
        gw.record(76)
        gw.record(76, skip=3)
        gw.record(77)
        gw.record(77)
        gw.restart()
        gw.status()
        gw.record(76)
        events = take(sub, 6)
    messages = [e for e in events if isinstance(e, Message)]
    statuses = [e for e in events if isinstance(e, Status)]
    assert [m.gap for m in messages] == [0, 3, 0, 0, 0]
    assert sub.lost == {(gw.endpoint, 76): 3}
    assert messages[-1].restarted and not any(m.restarted for m in messages[:-1])
    assert statuses[-1].restarted and sub.restarts[gw.endpoint] == 1
    assert statuses[-1].nodes == [{"node": 76}]


def test_several_gateways_are_told_apart(context):
    first, second = Gateway(context), Gateway(context)
    with Subscriber([first.endpoint, second.endpoint], nodes=[76]) as sub:
        connected(sub, first, second)
        first.record(76)
        second.record(76)
        second.record(76)
        events = take(sub, 3)
    assert sorted((e.gateway, e.seq) for e in events) == sorted(
        [(first.endpoint, 1), (second.endpoint, 1), (second.endpoint, 2)])
    assert sub.lost == {}


def test_a_gateway_added_later_is_read_and_its_silence_counts_from_then(context):
    """A gateway found after the others (gx2ctl tail of several takes each as found)
    is subscribed to as those given were; a bad endpoint adds nothing."""
    first, second = Gateway(context), Gateway(context)
    with Subscriber(first.endpoint, nodes=[76]) as sub:
        connected(sub, first)
        made = time.monotonic()
        sub.add(second.endpoint)
        sub.add(second.endpoint)  # (again: nothing more)
        assert sub.endpoints == [first.endpoint, second.endpoint]
        assert sub.silent_for(second.endpoint) <= time.monotonic() - made
        with pytest.raises(GatewayError, match="cannot subscribe to tcp://nowhere"):
            sub.add("tcp://nowhere")
        assert sub.endpoints == [first.endpoint, second.endpoint]
        connected(sub, first, second)
        second.record(76)
        [event] = take(sub, 1)
    assert (event.gateway, event.seq) == (second.endpoint, 1)
    assert sub.restarts == {first.endpoint: 0, second.endpoint: 0}


def all_queued(sub: Subscriber) -> bool:
    """Whether every gateway's socket of ``sub`` has a message waiting (white box: the
    public API cannot look without taking one)."""
    poller = zmq.Poller()
    for socket in sub._sockets:
        poller.register(socket, zmq.POLLIN)
    return len(poller.poll(0)) == len(sub._sockets)


def test_gateways_with_backlogs_are_read_in_turn(context):
    first, second = Gateway(context), Gateway(context)
    backlog, taken = 400, 200
    with Subscriber([first.endpoint, second.endpoint], nodes=[76, 77]) as sub:
        connected(sub, first, second)
        for _ in range(backlog):
            first.record(76)
            second.record(77)
        wait_for(lambda: all_queued(sub), 5, "both backlogs to reach the subscriber")
        reading = time.monotonic()
        events = take(sub, taken)
        second_silent = sub.silent_for(second.endpoint)
        read_for = time.monotonic() - reading
    counts = {node: sum(e.node == node for e in events) for node in (76, 77)}
    assert len(events) == taken
    assert min(counts.values()) >= 0.4 * taken, f"one gateway starved the other: {counts}"
    assert second_silent < read_for, "the second gateway looked silent while it published"


def test_a_gateway_only_beating_is_heard_beside_a_busy_one(context):
    busy, quiet = Gateway(context), Gateway(context)
    with Subscriber([busy.endpoint, quiet.endpoint], status=True) as sub:
        connected(sub, busy, quiet)
        for _ in range(400):
            busy.record(76)
        quiet.status()
        wait_for(lambda: all_queued(sub), 5, "the record and the heartbeat to be queued")
        reading = time.monotonic()
        events = take(sub, 10)
        quiet_silent = sub.silent_for(quiet.endpoint)
        read_for = time.monotonic() - reading
    assert any(isinstance(e, Status) and e.gateway == quiet.endpoint for e in events), \
        "the heartbeat waited behind the other gateway's backlog"
    assert quiet_silent < read_for


def test_malformed_messages_are_skipped_and_counted(context):
    gw = Gateway(context)
    problems: list[str] = []
    with Subscriber(gw.endpoint, on_malformed=lambda e, p: problems.append(str(p))) as sub:
        connected(sub, gw)
        for frames in ([b"gx2/76/one"], [b"gx2/76/x", b"\xc1"],
                       [b"gx2/76/x", msgpack.packb([1])], [b"gx2/76/x", msgpack.packb({})]):
            gw.socket.send_multipart(frames)
        gw.record(76)
        [message] = take(sub, 1)
    assert message.seq == 1 and sub.malformed == 4
    assert any("not msgpack" in p for p in problems) and any("seq" in p for p in problems)
    assert isinstance(Malformed("x"), Exception)


def test_curve_keys_let_a_subscriber_read_an_encrypted_stream(context, tmp_path: Path):
    curve.generate(tmp_path / "server")
    curve.generate(tmp_path / "client")
    server = curve.load_key_pair(tmp_path / "server.key_secret")
    gw = Gateway(context, server)
    keys = curve.load_client_keys(tmp_path / "client.key_secret", str(tmp_path / "server.key"))
    with Subscriber(gw.endpoint, keys=keys) as sub:
        connected(sub, gw)
        gw.record(76)
        [message] = take(sub, 1)
    assert message.node == 76


def test_a_monitor_takes_the_heartbeat_and_no_record_reaches_it(context):
    gw = Gateway(context)
    with Subscriber(gw.endpoint, status="only") as sub:
        connected(sub, gw)
        for _ in range(50):
            gw.record(76)
        gw.status()
        events = take(sub, 1)
        while (event := sub.receive(0.2)) is not None:  # (all that is queued for it)
            events.append(event)
    assert events and all(isinstance(e, Status) for e in events), events
    assert sub.lost == {}  # the records were never sent to it at all
    with pytest.raises(ValueError, match="status must be"):
        Subscriber(gw.endpoint, status="all")  # type: ignore[arg-type]
