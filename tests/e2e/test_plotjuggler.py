"""PlotJuggler's recipe (docs/live.md), checked by a subscriber configured as the recipe
configures PlotJuggler's "ZMQ Subscriber": it connects to the publish endpoint, subscribes
to the topic filter given, takes each message as [topic, payload], parses the payload
with a MessagePack parser and flattens it as PlotJuggler's parser does (a series per
number, named topic/field, arrays by index: ``gx2/76/accel_angrate/accel[0]``), its
time the ``time`` field. PlotJuggler itself needs a display; what it is given is this."""

from __future__ import annotations

import math
from itertools import pairwise
from typing import Any

import msgpack
import zmq

from gateway.sim.node import NodeSettings
from tests.helpers.waiting import wait_for

FILTER = "gx2/76/"
"""The recipe's topic filter: every record of node 76."""
TIME_FIELD = "time"
"""The recipe's "use field as timestamp" field."""


def flattened(prefix: str, value: Any, into: dict[str, float]) -> None:
    """A message's numbers as PlotJuggler's MessagePack parser names them."""
    if isinstance(value, dict):
        for key, item in value.items():
            flattened(f"{prefix}/{key}", item, into)
    elif isinstance(value, list):
        for index, item in enumerate(value):
            flattened(f"{prefix}[{index}]", item, into)
    elif isinstance(value, bool | int | float):
        into[prefix] = float(value)


def test_the_plotjuggler_recipe_gives_a_series_per_field_on_the_sample_clock(
        simulator, gateway, zmq_context) -> None:
    sim = simulator(NodeSettings(76, stream="accel_angrate"), NodeSettings(77, stream="euler"))
    gw = gateway(sim.path, [{"address": 76, "stream": "accel_angrate"},
                            {"address": 77, "stream": "euler"}])
    gw.wait_streaming(76, 77)
    host, port = gw.publish_endpoint.removeprefix("tcp://").rsplit(":", 1)
    socket = zmq_context.socket(zmq.SUB)
    socket.connect(f"tcp://{'localhost' if host == '127.0.0.1' else host}:{port}")
    socket.setsockopt_string(zmq.SUBSCRIBE, FILTER)
    series: dict[str, list[tuple[float, float]]] = {}
    topics: set[str] = set()

    def received() -> bool:
        for _ in range(50):
            if not socket.poll(100):
                break
            frames = socket.recv_multipart()
            assert len(frames) == 2, "PlotJuggler reads [topic, payload]"
            topic = frames[0].decode()
            payload = msgpack.unpackb(frames[1])
            topics.add(topic)
            numbers: dict[str, float] = {}
            flattened(topic, payload, numbers)
            stamp = payload[TIME_FIELD]
            for name, value in numbers.items():
                series.setdefault(name, []).append((stamp, value))
        return len(series.get("gx2/76/accel_angrate/accel[2]", ())) >= 100
    try:
        wait_for(received, 10, "100 samples of node 76's accel")
    finally:
        socket.close(linger=0)
    assert topics == {"gx2/76/accel_angrate"}  # the filter keeps node 76 alone
    for axis in range(3):
        assert f"gx2/76/accel_angrate/ang_rate[{axis}]" in series
    accel_z = series["gx2/76/accel_angrate/accel[2]"]
    stamps = [t for t, _ in accel_z]
    assert all(b > a for a, b in pairwise(stamps)), "time increases"
    assert all(math.isfinite(v) for _, v in accel_z)
    # on the sample clock: 100 Hz samples are 10 ms apart
    steps = sorted(b - a for a, b in pairwise(stamps))
    assert abs(steps[len(steps) // 2] - 0.01) < 0.001, steps[len(steps) // 2]
