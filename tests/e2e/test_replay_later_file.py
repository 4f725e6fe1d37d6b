"""A later file of a rotated recording, replayed without the files before it (deleted
by retention, or copied away alone): it publishes the records it holds with the
recorded ``seq``, ``device_time`` (the timer's wraps before it counted), ``host_time``
and every field, and ``time`` from an estimate of the nodes' clocks begun at the file
(docs/interface.md, section 7)."""

from __future__ import annotations

from aspp.timing import WRAP_SECONDS
from gateway.common.jsontext import strict
from gateway.sim.base_station import RADIO_LATENCY
from gateway.sim.node import NodeSettings
from tests.e2e.test_recording import messages, node_records, payloads, recorded
from tests.helpers.waiting import wait_for

NODES = [{"address": 76}, {"address": 77}]
SETTLED_S = 2.0
"""Seconds into the file after which ``time`` is within TIME_S of the recorded one."""
TIME_S = 1e-3
WRAP_IN_S = 5.0
"""Seconds from the simulator's start to the nodes' timers wrapping: while recording."""


def test_a_later_file_replays_the_recorded_seq_and_times(simulator, gateway, tmp_path):
    directory = tmp_path / "recordings"
    start = WRAP_SECONDS - WRAP_IN_S
    sim = simulator(NodeSettings(76, stream="accel_angrate", ppm=45.0, timer_start=start),
                    NodeSettings(77, stream="accel_angrate", ppm=-38.0, timer_start=start))
    live = gateway(sim.path, NODES, base_station={"latency_ms": RADIO_LATENCY * 1000},
                   record={"directory": str(directory), "rotate_mb": 0.04})
    live.wait_streaming(76, 77)
    wait_for(lambda: len(list(directory.glob("*.mcap"))) >= 6, 60, "six files")
    assert live.terminate()[0] == 0, live.log()
    # the files before the one the timers wrapped in deleted (as retention deletes
    # them): what is left begins with a node's seq in the hundreds and its device time
    # a wrap on
    for path in sorted(directory.glob("*.mcap")):
        times = [p["device_time"] for _, p, _ in node_records(messages(path))]
        path.unlink()
        if max(times) > WRAP_SECONDS:
            break
    want = {key: payload for key, (_, payload) in payloads(recorded(directory)).items()}
    assert min(seq for _, seq in want) > 100
    assert min(p["device_time"] for p in want.values()) > WRAP_SECONDS

    replay = gateway(f"replay://{directory}?speed=0&exit=true&delay=2", NODES,
                     base_station={"latency_ms": RADIO_LATENCY * 1000})
    sub = replay.subscribe("gx2/")
    wait_for(lambda: replay.proc.poll() is not None, 60, "the replay to end (exit=true)")
    assert replay.proc.returncode == 0, replay.log()
    sub.drain_until_quiet()
    played = {(p["node"], p["seq"]): strict(p) for t, p in sub.messages if t[4].isdigit()}
    # every record, under its recorded seq, with the recorded device_time, host_time
    # and fields; but one whose packet began in the file deleted, if the file's first
    # read holds its end (a read of the pty is usually a packet or more, but not always)
    missing = want.keys() - played.keys()
    assert played.keys() <= want.keys() and len(missing) <= 1, sorted(missing)[:5]
    assert all(seq == min(s for n, s in want if n == node) for node, seq in missing)
    first = min(p["host_time"] for p in want.values())
    settled = 0
    for key, again in played.items():
        payload = want[key]
        assert {**again, "time": None} == {**payload, "time": None}, key
        if payload["host_time"] - first >= SETTLED_S:
            assert abs(again["time"] - payload["time"]) <= TIME_S, key
            settled += 1
    assert settled > 100
