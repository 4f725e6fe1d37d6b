"""Stopping a stream over a radio that loses 0xFA, through a real pty: retried until
the stream is silent, and nothing arrives after the stop returns."""

from __future__ import annotations

import time
from pathlib import Path

from gateway.sim.base_station import RadioLink
from gateway.sim.node import NodeSettings
from tests.helpers.simulated import continuous

REPO = Path(__file__).resolve().parents[2]
CLI_TIMEOUT = 15.0
"""Seconds a `gx2-gateway` run with a bad configuration may take before it counts as hung."""


# -- 3. stop under 0xFA loss -----------------------------------------------------------------------

STOP_SEEDS = (1, 2, 3)
STOPS_PER_SEED = 2
EXTRA_STOPS = 6
"""On the last seed, more stops while none has needed a second attempt (each does with
probability about 1/2, so 12 stops all done at the first try is 1 in 4096)."""


def stop_accounting(sim, node: int) -> int:
    """Stop commands the node received plus commands lost over the radio (only stops are
    lost here): one per stop packet the gateway sent."""
    def count(station, now) -> int:
        log = station.nodes[node].log.commands
        stops = [c for c in log if c.code == 0xFA or (
            c.code == 0xC4 and c.arguments.get("continuous_command") == 0)]
        return len(stops) + station.stats.commands_lost
    return sim.call(count)


def test_stop_under_stop_loss(simulator, gateway):
    attempts: list[int] = []
    for seed in STOP_SEEDS:
        sim = simulator(NodeSettings(76), radio={76: RadioLink(stop_loss=0.5)}, seed=seed)
        gw = gateway(sim.path, [{"address": 76, "stream": "euler"}])
        gw.wait_streaming(76)
        sub = gw.subscribe("gx2/76/")
        stops = STOPS_PER_SEED + (EXTRA_STOPS if seed == STOP_SEEDS[-1] else 0)
        for cycle in range(stops):
            if cycle >= STOPS_PER_SEED and max(attempts) > 1:
                break
            if cycle:
                started = gw.control.result("start", node=76, record="euler")
                assert started["record"] == "euler"
            since = time.time()
            sub.until(lambda m, since=since: any(
                p.get("record") == "euler" and p["host_time"] > since for _, p in m),
                5, f"seed {seed}: node 76 streaming")
            sent_before = stop_accounting(sim, 76)

            result = gw.control.result("stop", timeout=30, node=76)
            returned = time.time()
            assert result["node"] == 76
            assert result["attempts"] >= 1, result
            assert isinstance(result["elapsed"], float) and 0 < result["elapsed"] < 20, result
            streams = continuous(sim, 76)
            sub.drain(0.6)
            records = sub.records(76)
            late = [p for p in records if p["host_time"] > returned]
            first_late = len(records) - len(late)
            around = [(p["record"], p["seq"], round(p["host_time"] - returned, 3))
                      for p in records[max(0, first_late - 3):first_late + 3]]
            assert streams == 0, (f"seed {seed}: 'stop' {result} returned, node 76 streams; "
                                  f"(record, seq, s after the return): {around}")
            assert late == [], (f"seed {seed}: {len(late)} records after the stop {result} "
                                f"returned; (record, seq, s after the return): {around}")
            assert stop_accounting(sim, 76) - sent_before == result["attempts"], \
                (seed, result, "attempts differ from the stop packets the node saw or lost")
            assert gw.node_status(76)["state"] != "streaming"
            attempts.append(result["attempts"])
        status, _ = gw.terminate()
        assert status == 0
        sim.stop()
    assert max(attempts) > 1, f"no stop needed a second attempt at 50% loss: {attempts}"
