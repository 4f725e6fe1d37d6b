"""Sample time through the real gateway and simulator: each record's ``time`` against
the instant the simulated node really took the sample (the simulator keeps it per
timer reading, on the host's monotonic clock), on a loaded link with stalls, two nodes
with crystals tens of ppm apart."""

from __future__ import annotations

import statistics
import time
from itertools import pairwise
from typing import Any

import pytest

from aspp.timing import TICKS_PER_SECOND
from gateway.sim.base_station import RADIO_LATENCY, LineFaults
from gateway.sim.node import NodeSettings
from tests.helpers.waiting import wait_for

# (favoured, tests/conftest.py: what these tests assert is where the line places each
# packet, and the simulator writing them runs in the test's own process)
pytestmark = pytest.mark.usefixtures("favoured_host")

WARM_UP = 3.0
"""Seconds of each stream left out (the estimate locks within 2 s of its start)."""


def unix_minus_monotonic() -> float:
    """The UNIX clock less the monotonic one, as the gateway sees them (a median of a
    few readings: a reading interrupted between the two calls is off)."""
    return statistics.median(time.time() - time.monotonic() for _ in range(9))


def true_times(sim, node: int, records: list[dict[str, Any]]) -> list[float]:
    """When each record was really sampled, on the UNIX clock."""
    sampled = sim.call(lambda station, now: dict(station.nodes[node].sampled))
    shift = unix_minus_monotonic()
    return [sampled[r["timer"]] + shift for r in records]


def errors(sim, node: int, records: list[dict[str, Any]], field: str) -> list[float]:
    return [r[field] - t for r, t in zip(records, true_times(sim, node, records), strict=True)]


def spread(values: list[float]) -> tuple[float, float]:
    """(p99, max) of |value - median|."""
    middle = statistics.median(values)
    deviations = sorted(abs(v - middle) for v in values)
    return deviations[int(0.99 * (len(deviations) - 1))], deviations[-1]


def streamed(messages: list[tuple[str, dict]], node: int) -> list[dict[str, Any]]:
    return [p for t, p in messages if t == f"gx2/{node}/accel_angrate"]


def test_time_is_the_sample_instant_on_a_loaded_link_with_stalls(simulator, gateway):
    # two nodes at 129 and 125 Hz with accel_angrate: about 90% of the 115200 baud line;
    # the base station holds its output back for 40 ms twice a second. (Rates a little
    # apart: at one rate, one node's packets can wait behind the other's for tens of
    # seconds, which README describes and bench/timesync.py measures.)
    sim = simulator(NodeSettings(76, divider=397, stream="accel_angrate", ppm=45.0),
                    NodeSettings(77, divider=409, stream="accel_angrate", ppm=-38.0),
                    line=LineFaults(stall_rate=2.0, stall_ms=40.0))
    gw = gateway(sim.path, [{"address": 76}, {"address": 77}],
                 base_station={"latency_ms": RADIO_LATENCY * 1000})
    sub = gw.subscribe("gx2/76/accel_angrate", "gx2/77/accel_angrate")
    sub.drain(WARM_UP + 5.0)
    assert sim.station.stats.stalls >= 5

    per_node = {}
    for node in (76, 77):
        records = streamed(sub.messages, node)
        assert all("time" in r for r in records)
        times = [r["time"] for r in records]
        assert all(b > a for a, b in pairwise(times)), "time went back or stood still"
        first = records[0]["device_time"]
        settled = [r for r in records if r["device_time"] - first > WARM_UP]
        assert len(settled) > 400
        per_node[node] = settled
        sample, host = errors(sim, node, settled, "time"), errors(sim, node, settled, "host_time")
        p99, worst = spread(sample)
        host_p99, _ = spread(host)
        # (bench/timesync.py measures these against the targets README gives; here
        # with room for a loaded CI machine, whose scheduling adds to every delay, and
        # for the estimate's drift, fitted over a few seconds only; still well inside
        # what a wrong mapping costs: the line time of a packet is 3.5 ms, the radio's
        # latency 3 ms, a stall 40 ms)
        assert p99 <= 2e-3 and worst <= 3e-3, (p99, worst)
        assert abs(statistics.median(sample)) <= 2e-3, statistics.median(sample)
        # the stalls and the queue are in host_time, not in time
        assert host_p99 > 10 * p99, (host_p99, p99)

    # the two nodes share one clock: their errors agree
    bias = [statistics.median(errors(sim, n, per_node[n], "time")) for n in (76, 77)]
    assert abs(bias[0] - bias[1]) <= 1.5e-3, bias

    # status shows each node's estimate, locked (8 s of a loaded line are too short a
    # base line for the drift to be near the crystal's yet: tens of ppm, sometimes a
    # hundred; the unit tests check the drift over longer streams)
    clocks = {n["node"]: n["clock"] for n in gw.status()["nodes"]}
    for node in (76, 77):
        assert clocks[node]["locked"] is True
        assert abs(clocks[node]["offset"] - time.time()) < 60, clocks[node]
        assert abs(clocks[node]["drift_ppm"]) <= 500 and clocks[node]["spread_ms"] >= 0


def test_a_reboot_starts_a_new_estimate_that_locks_within_two_seconds(simulator, gateway):
    sim = simulator(NodeSettings(76, divider=512, stream="accel_angrate", ppm=60.0))
    gw = gateway(sim.path, [{"address": 76, "stream": "accel_angrate"}])
    gw.wait_streaming(76)
    sub = gw.subscribe("gx2/76/accel_angrate")
    sub.drain(2.0)
    sim.reboot(76)  # the timer starts again from 0, the stream resumes on its own
    wait_for(lambda: gw.node_status(76)["reboots"] >= 1, 10, "the reboot noticed")
    sub.drain(4.0)
    records = streamed(sub.messages, 76)
    # (device_time goes on through a reboot; the timer starts again)
    after = records[next(i for i, (a, b) in enumerate(pairwise(records))
                         if b["timer"] < a["timer"]) + 1:]
    assert after[0]["timer"] < 5 * TICKS_PER_SECOND, "not the rebooted stream"
    sample = errors(sim, 76, after, "time")
    locked = [e for r, e in zip(after, sample, strict=True)
              if r["device_time"] - after[0]["device_time"] > 2.0]
    assert len(locked) > 100
    middle = statistics.median(locked)
    assert abs(middle) <= 2e-3 and spread(locked)[1] <= 3e-3
    assert gw.node_status(76)["clock"]["locked"] is True
