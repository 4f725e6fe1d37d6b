"""A replay played faster than recorded (``speed=5``, ``speed=0``) judges its serial line
on the recording's own times: a line the recording shows at 90% is not over capacity
however fast the bytes are played, so the nodes' clocks are never held and every
record's ``time`` is the recorded one."""

from __future__ import annotations

import time
from pathlib import Path

from gateway.common.jsontext import strict
from gateway.sim.base_station import RADIO_LATENCY
from gateway.sim.node import NodeSettings
from tests.e2e.test_recording import payloads, recorded

NODES = [{"address": 76}, {"address": 77}]
RECORD_S = 12.0
OVER = "line over capacity"
DELAY_S = 4.5
"""Seconds before the replay plays. A gateway judges its line over the last five seconds
once it has four of them (gateway/daemon/station/lineload.py): a replay that begins after that
is judged, by a gateway that counts the bytes as they are played, while it plays."""


def near_full_recording(simulator, gateway, directory: Path) -> dict:
    """Two nodes at 129 and 125 Hz with accel_angrate, about 90% of the 115200 baud line
    (as tests/e2e/test_sample_time.py), recorded for RECORD_S: (node, seq) -> payload."""
    sim = simulator(NodeSettings(76, divider=397, stream="accel_angrate", ppm=45.0),
                    NodeSettings(77, divider=409, stream="accel_angrate", ppm=-38.0))
    live = gateway(sim.path, NODES, base_station={"latency_ms": RADIO_LATENCY * 1000},
                   record={"directory": str(directory)})
    live.wait_streaming(76, 77)
    live.subscribe("gx2/gateway/status").drain(RECORD_S)
    assert live.terminate()[0] == 0, live.log()
    assert OVER not in live.log()  # (live, the line had room)
    return {key: payload for key, (_, payload) in payloads(recorded(directory)).items()}


def test_a_fast_replay_judges_the_line_on_the_recorded_times(simulator, gateway, tmp_path):
    directory = tmp_path / "recordings"
    live = near_full_recording(simulator, gateway, directory)
    assert len(live) > 0.9 * RECORD_S * (129 + 125)
    for speed in (5, 0):
        replay = gateway(f"replay://{directory}?speed={speed}&delay={DELAY_S}", NODES,
                         base_station={"latency_ms": RADIO_LATENCY * 1000})
        started = time.monotonic()
        sub = replay.subscribe("gx2/76/", "gx2/77/")
        sub.until(lambda _, gw=replay: gw.status()["replay"]["finished"], 30,
                  "the replay to end")
        # past the second a wall-clock judge would have seen the played bytes in (at
        # speed=0 the whole recording is played in less than that)
        sub.drain(max(0.5, started + DELAY_S + 2.5 - time.monotonic()))
        played = {(p["node"], p["seq"]): strict(p) for _, p in sub.messages}
        assert played.keys() == live.keys(), speed
        moved = [key for key, payload in live.items()
                 if played[key]["time"] != payload["time"]]
        assert not moved, (speed, f"{len(moved)} of {len(live)} records with another time")
        assert OVER not in replay.log(), speed
        assert replay.status()["link"].get("over_capacity") is not True
        assert replay.terminate()[0] == 0
