"""The publisher: topics and msgpack on a real PUB, through pyzmq's compiled send where
pyzmq has one and through its plain send where it does not."""

from __future__ import annotations

import math

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
