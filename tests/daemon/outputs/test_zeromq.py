"""The publisher: topics and msgpack on a real PUB, through pyzmq's compiled send where
pyzmq has one and through its plain send where it does not."""

from __future__ import annotations

import math
import threading
import time

import msgpack
import pytest
import zmq

from gateway.daemon.outputs import Outputs
from gateway.daemon.outputs import zeromq as publishing
from gateway.daemon.outputs.zeromq import Publisher, compiled_send


def published(monkeypatch: pytest.MonkeyPatch | None = None) -> list[list[bytes]]:
    context = zmq.Context()
    try:
        publisher = Publisher(context, "inproc://published", 100)
        outputs = Outputs({"zeromq": publisher})
        sub = context.socket(zmq.SUB)
        sub.setsockopt(zmq.SUBSCRIBE, b"gx2/")
        sub.connect("inproc://published")
        got: list[list[bytes]] = []
        for seq in range(1, 1000):  # until the subscription has reached the PUB
            outputs.publish(76, "euler", {"seq": seq, "roll": math.nan})
            if sub.poll(10):
                got.append(sub.recv_multipart())
                break
        outputs.status({"gateway": {}})
        assert sub.poll(1000)
        got.append(sub.recv_multipart())
        sub.close(0)
        publisher.close()
        return got
    finally:
        context.term()


def test_records_and_status_go_out_as_topic_and_msgpack() -> None:
    (topic, payload), (status_topic, status) = published()
    assert topic == b"gx2/76/euler" and status_topic == b"gx2/gateway/status"
    assert math.isnan(msgpack.unpackb(payload)["roll"])
    assert msgpack.unpackb(status) == {"gateway": {}}


def test_the_compiled_send_is_used_where_pyzmq_has_it() -> None:
    context = zmq.Context()
    socket = context.socket(zmq.PUB)
    try:
        send = compiled_send(socket)
        assert send.__func__ is zmq.backend.Socket.send  # type: ignore[attr-defined]
    finally:
        socket.close(0)
        context.term()


def test_without_a_compiled_send_the_plain_one_publishes(monkeypatch) -> None:
    monkeypatch.setattr(publishing.zmq.backend, "Socket", type("NoSend", (), {}))
    context = zmq.Context()
    socket = context.socket(zmq.PUB)
    try:
        assert compiled_send(socket) == socket.send
    finally:
        socket.close(0)
        context.term()
    (topic, _), _ = published()
    assert topic == b"gx2/76/euler"


def test_what_was_published_before_close_reaches_a_slow_subscriber_within_the_budget():
    """A replay that exits (``exit=true``) publishes its last records just before it
    closes: a subscriber still reading them gets them all if it reads within the
    seconds close was given, not the last only of what the socket's buffers held."""
    count, budget = 20000, 3.0
    gateway, reader = zmq.Context(), zmq.Context()
    sub = reader.socket(zmq.SUB)
    sub.setsockopt(zmq.RCVHWM, 10)  # the rest waits at the publisher, as with a slow
    sub.setsockopt(zmq.RCVBUF, 4096)  # subscriber on a busy host
    sub.setsockopt(zmq.SUBSCRIBE, b"gx2/")
    try:
        publisher = Publisher(gateway, "tcp://127.0.0.1:*", count + 10)
        sub.connect(publisher.socket.getsockopt(zmq.LAST_ENDPOINT).decode())
        while not sub.poll(10):  # until the subscription has reached the PUB
            publisher.send(b"gx2/76/euler", {"seq": 0})
        while sub.poll(100):
            sub.recv_multipart()
        padding = "x" * 500
        for seq in range(1, count + 1):
            assert publisher.send(b"gx2/76/euler", {"seq": seq, "padding": padding})
        publisher.close(budget)
        closed = threading.Thread(target=gateway.term)
        started = time.monotonic()
        closed.start()
        time.sleep(0.5)  # the subscriber, busy elsewhere, comes back to read
        got = []
        while sub.poll(1000):
            got.append(msgpack.unpackb(sub.recv_multipart()[1])["seq"])
        closed.join(budget)
        assert not closed.is_alive() and time.monotonic() - started < budget + 1.0
        assert got == list(range(1, count + 1))
    finally:
        sub.close(0)
        reader.term()


def test_a_subscriber_that_never_reads_holds_the_close_no_longer_than_its_seconds():
    """The other side of the linger: the gateway's exit stays within its promise."""
    gateway, reader = zmq.Context(), zmq.Context()
    sub = reader.socket(zmq.SUB)
    sub.setsockopt(zmq.RCVHWM, 10)
    sub.setsockopt(zmq.RCVBUF, 4096)
    sub.setsockopt(zmq.SUBSCRIBE, b"gx2/")
    try:
        publisher = Publisher(gateway, "tcp://127.0.0.1:*", 30_000)
        sub.connect(publisher.socket.getsockopt(zmq.LAST_ENDPOINT).decode())
        while not sub.poll(10):
            publisher.send(b"gx2/76/euler", {"seq": 0})
        for seq in range(1, 20_001):
            publisher.send(b"gx2/76/euler", {"seq": seq, "padding": "x" * 500})
        closed_at = time.monotonic()
        publisher.close(0.5)
        ended = threading.Thread(target=gateway.term, daemon=True)
        ended.start()
        ended.join(3.0)
        assert not ended.is_alive(), "the close held the context's end past its seconds"
        assert 0.4 < time.monotonic() - closed_at < 1.5
    finally:
        sub.close(0)
        reader.term()
