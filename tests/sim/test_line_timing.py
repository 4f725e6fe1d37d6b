"""gx2-sim puts each packet on the pty when its line model says the last byte is sent.

The host's clock estimate (aspp.clock) sees any lateness of the simulator as radio
delay, so a simulator that writes late makes bench/timesync.py measure the simulator,
not the gateway. The loop used to sleep on epoll, whose timeout is whole milliseconds:
every packet went out 0-1 ms late (issue 21).
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path

import pytest
import serial

from aspp import Decoder, Reply, decode
from aspp.frame import HEADER_SIZE
from aspp.timing import byte_time
from gateway.sim.base_station import RADIO_LATENCY, BaseStation, RadioLink
from gateway.sim.node import NodeSettings
from gateway.sim.server import Simulator

BAUD = 115200
PACKETS = 150
DEADLINE = 10.0
SPREAD = 0.2e-3
"""Of the lateness, p50 - p10: what the host's clock estimate rests on is its fastest
packets, and a constant part (the pty's own, some 0.2 ms here) is a bias that
latency_ms takes out. With select(2) the spread is 0.03 to 0.07 ms here; with epoll's
whole milliseconds 0.37 to 0.48 ms (a wake-up rounded up by a uniform 0-1 ms). The
slower half is left out: a machine busy with other work (the suite's other processes
on two cores) wakes the simulator late now and then, and p90 - p10 was 0.11 to 0.57 ms
with select(2) in six measurements beside them."""
ATTEMPTS = 3
"""Measurements of PACKETS, the spread judged on the best: a machine's load passes, and a
loop that sleeps in whole milliseconds is late in every one."""


def lateness(link: Path) -> list[float]:
    """Seconds each packet after the first ten reached the host after its last byte
    could have been sent (its sample, RADIO_LATENCY, its bytes on the line)."""
    # one node alone, no random radio delay: a packet reaches the base station
    # RADIO_LATENCY after its sample and is on the host's side once its bytes are sent
    sim = Simulator([NodeSettings(76, divider=592, stream="accel_angrate")], link=link,
                    radio={76: RadioLink(jitter=0.0)}).start()
    try:
        port = serial.Serial(str(link), BAUD, timeout=0.05)
        decoder = Decoder()
        received: list[tuple[int, int, float]] = []  # (timer, packet bytes, read at)
        deadline = time.monotonic() + DEADLINE
        try:
            while len(received) < PACKETS and time.monotonic() < deadline:
                data = port.read(port.in_waiting or 1)
                now = time.monotonic()
                for event in decoder.feed(data):
                    if isinstance(event, Reply):
                        record = decode(event.raw, HEADER_SIZE, len(event.raw) - 4)
                        timer = dict(zip(record.spec.field_names, record.values,
                                         strict=True))["timer"]
                        received.append((timer, len(event.raw), now))
        finally:
            port.close()

        def sampled(station: BaseStation, _: float) -> dict[int, float]:
            return dict(station.nodes[76].sampled)

        truth = sim.call(sampled)
    finally:
        sim.stop()
    assert len(received) >= PACKETS, f"{len(received)} packets in {DEADLINE} s"
    per_byte = byte_time(BAUD)
    late = [read - (truth[timer] + RADIO_LATENCY + size * per_byte)
            for timer, size, read in received[10:] if timer in truth]
    assert len(late) >= PACKETS - 20
    assert min(late) > -50e-6, "a packet read before its bytes could have been sent"
    return late


@pytest.mark.usefixtures("favoured_host")  # (the demo beside the suite: 0.9 ms once)
def test_packets_reach_the_host_when_the_line_model_sends_them(tmp_path: Path) -> None:
    spreads = []
    for attempt in range(ATTEMPTS):
        deciles = statistics.quantiles(lateness(tmp_path / f"gx2-{attempt}"), n=10)
        spreads.append((deciles[4] - deciles[0], deciles[0], deciles[4]))
        if spreads[-1][0] < SPREAD:
            return
    raise AssertionError("packets reach the host " + ", ".join(
        f"{low * 1e3:.2f} to {high * 1e3:.2f}" for _, low, high in spreads)
        + f" ms late (p10 to p50) in each of {ATTEMPTS} measurements")
