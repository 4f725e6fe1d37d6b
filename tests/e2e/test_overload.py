"""A serial line over capacity (issue 21): three nodes at 100 Hz, one streaming
``accel_angrate_orientation``, send about 135% of what 115200 baud carries. The
simulated base station's buffer fills and drops, as a real one's does, and every packet
read waits behind up to a buffer's worth of others: the delay the clock estimate sees is
the backlog's, not the clock's. The gateway must say so (the gateway and the nodes it
affects WARN, their clocks unlocked), keep ``time`` smooth against ``device_time``
meanwhile, and be back on the truth within 10 s of the line having room."""

from __future__ import annotations

import time
from itertools import pairwise

from aspp.timing import sample_period
from gateway.sim.base_station import RADIO_LATENCY
from gateway.sim.node import NodeSettings
from tests.e2e.test_sample_time import errors
from tests.helpers.waiting import wait_for

DIVIDER = 512
"""100 Hz."""
OVER = "line over capacity: sample times unreliable"
ROOM_S = 10.0
"""Seconds from the line having room to the estimate being back within 1 ms."""


def test_an_overloaded_line_is_said_and_time_stays_smooth(simulator, gateway):
    sim = simulator(NodeSettings(76, divider=DIVIDER, stream="accel_angrate", ppm=30.0),
                    NodeSettings(77, divider=DIVIDER, stream="accel_angrate", ppm=-20.0),
                    NodeSettings(78, divider=DIVIDER, stream="accel_angrate_orientation"))
    gw = gateway(sim.path, [{"address": 76}, {"address": 77}, {"address": 78}],
                 base_station={"latency_ms": RADIO_LATENCY * 1000})
    sub = gw.subscribe("gx2/76/accel_angrate", "gx2/77/accel_angrate")

    def over_capacity() -> bool:
        status = gw.status()
        nodes = {n["node"]: n for n in status["nodes"]}
        return (status["link"].get("over_capacity") is True
                and any(r.startswith("line over capacity") for r in status["gateway"]["reasons"])
                and all(OVER in nodes[n]["reasons"] and nodes[n]["health"] == "WARN"
                        and nodes[n]["clock"]["locked"] is False for n in (76, 77, 78)))

    wait_for(over_capacity, 15, "the line said to be over capacity, its nodes WARN, unlocked")
    assert sim.station.stats.packets_dropped_full > 0, "the simulated line was not full"
    sub.drain(3.0)  # a while over capacity
    gw.control.result("stop", timeout=30, node=78)
    room = time.monotonic()
    wait_for(lambda: not gw.status()["link"].get("over_capacity"), 10, "the line to have room")
    sub.drain(room + ROOM_S + 2.0 - time.monotonic())
    status = gw.status()
    nodes = {n["node"]: n for n in status["nodes"]}

    period = sample_period(DIVIDER)
    for node in (76, 77):
        records = [p for t, p in sub.messages if t == f"gx2/{node}/accel_angrate"]
        # time strictly increasing, and never stepping against device_time by more than
        # a sample period (no node rebooted), overloaded or not
        steps = [(b["time"] - b["device_time"]) - (a["time"] - a["device_time"])
                 for a, b in pairwise(records)]
        assert all(b["time"] > a["time"] for a, b in pairwise(records))
        assert max(abs(s) for s in steps) <= period, max(steps, key=abs)
        # within 1 ms of the true sample instant from ROOM_S after the line had room
        unix_room = room + time.time() - time.monotonic()
        settled = [r for r in records if r["host_time"] >= unix_room + ROOM_S]
        assert len(settled) > 50
        worst = max(abs(e) for e in errors(sim, node, settled, "time"))
        assert worst <= 1e-3, f"node {node}: {worst * 1e3:.2f} ms off the truth"
        assert nodes[node]["clock"]["locked"] is True
        # the drift never beyond what a crystal can do, backlog or not
        assert abs(nodes[node]["clock"]["drift_ppm"]) <= 200
        assert OVER not in nodes[node]["reasons"]
    assert not any(r.startswith("line over capacity") for r in status["gateway"]["reasons"])
