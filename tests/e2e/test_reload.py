"""Reloading the configuration while the gateway runs (issue 35, part 3): SIGHUP
(``systemctl reload``) and ``gx2ctl reload`` add, remove and change nodes, and touch
nothing else. Through the installed gx2-gateway and gx2ctl, gx2-sim on a pty, and the
recording read back with the ``mcap`` package's own reader."""

from __future__ import annotations

import json
import os
import signal
import time
from itertools import pairwise

import yaml

from gateway.sim.node import NodeSettings
from gateway.sim.physics import Motion
from tests.e2e.test_recording import node_records, recorded
from tests.helpers.ports import free_port
from tests.helpers.processes import Running, gx2ctl
from tests.helpers.simulated import continuous, received
from tests.helpers.viewer import Viewer
from tests.helpers.waiting import wait_for

DIVIDER = 512
"""100 Hz."""
KEPT = {"address": 76, "stream": "accel_angrate"}
"""The node every reload here leaves alone."""
SWING = Motion(roll=0.3, pitch=-0.2, yaw_rate=0.5, swing=0.4)


def three_nodes(simulator):
    """Nodes 76, 77 and 78 powered on one base station, none streaming by itself."""
    return simulator(*(NodeSettings(a, divider=DIVIDER) for a in (76, 77, 78)))


def rewrite(gw, **changes) -> None:
    """The gateway's configuration file as it was, with ``changes`` (top-level keys)."""
    gw.path.write_text(yaml.safe_dump({**gw.config, **changes}))


def addresses(gw) -> set[int]:
    return {n["node"] for n in gw.status()["nodes"]}


def refusals(gw) -> list[str]:
    return [line for line in gw.log().splitlines() if "reload refused" in line]


def test_sighup_adds_one_node_removes_another_and_the_third_streams_on_without_a_gap(
        simulator, gateway, tmp_path):
    sim = three_nodes(simulator)
    directory = tmp_path / "recordings"
    gw = gateway(sim.path, [KEPT, {"address": 77, "stream": "euler"}],
                 record={"directory": str(directory)},
                 metrics={})
    sub = gw.subscribe("gx2/76/")
    gw.wait_streaming(76, 77)
    sub.drain(1.0)

    rewrite(gw, nodes=[KEPT, {"address": 78, "name": "new", "stream": "euler"}])
    reloaded_at = time.time()
    gw.proc.send_signal(signal.SIGHUP)
    wait_for(lambda: addresses(gw) == {76, 78}, 10, "77 gone and 78 added")
    gw.wait_streaming(78)
    wait_for(lambda: continuous(sim, 77) == 0, 10, "the removed node's stream stopped")
    stopped_at = time.time()
    status = gw.status()
    assert status["stations"][0]["nodes"] == [76, 78]
    assert next(n for n in status["nodes"] if n["node"] == 78)["name"] == "new"
    metrics = wait_for(lambda: _metrics(gw), 5, "the metrics")
    assert 'node="77"' not in metrics and 'node="78"' in metrics
    assert continuous(sim, 76) == 0xC2
    sub.drain(1.0)
    assert gw.terminate()[0] == 0, gw.log()
    assert "reloaded" in gw.log() and not refusals(gw)

    # what a subscriber had of 76: every seq, across the reload
    seqs = [p["seq"] for p in sub.records(76)]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), "a gap in 76's seq"
    # and what was recorded: every seq, and no sample missing on the node's own clock
    records = [p for topic, p, _ in node_records(recorded(directory))]
    kept = [p for p in records if p["node"] == 76]
    assert [p["seq"] for p in kept] == list(range(1, len(kept) + 1))
    assert kept[0]["host_time"] < reloaded_at - 1 and kept[-1]["host_time"] > reloaded_at + 1
    stream = [p for p in kept if p["record"] == "accel_angrate"]
    steps = {round(b["device_time"] - a["device_time"], 3) for a, b in pairwise(stream)}
    assert steps == {round(DIVIDER / 51200, 3)}, f"76's samples not continuous: {steps}"
    assert any(p["node"] == 78 for p in records)
    gone = [p for p in records if p["node"] == 77]
    assert gone and max(p["host_time"] for p in gone) < stopped_at


def _metrics(gw) -> str | None:
    import urllib.request
    try:
        with urllib.request.urlopen(f"http://{gw.config['metrics']['endpoint']}/metrics",
                                    timeout=2) as answer:
            text = answer.read().decode()
    except OSError:
        return None
    return text if "gx2_node_health" in text else None


def test_a_bad_reload_keeps_the_running_configuration_and_says_so_in_one_line(
        simulator, gateway):
    sim = three_nodes(simulator)
    gw = gateway(sim.path, [KEPT, {"address": 77, "stream": "euler"}])
    gw.wait_streaming(76, 77)
    config = str(gw.path)

    # a typo: refused, one line in the log, the running configuration kept
    rewrite(gw, nodes=[KEPT, {"adress": 78}])
    gw.proc.send_signal(signal.SIGHUP)
    wait_for(lambda: refusals(gw), 10, "the refusal in the log")
    [line] = [line for line in gw.log().splitlines() if ": reload" in line]
    assert "adress" in line and config in line and "kept" in line
    ran = gx2ctl("--config", config, "reload")
    assert ran.status == 2, ran
    assert ran.stdout == "" and len(ran.stderr.splitlines()) == 1 and "adress" in ran.stderr
    assert "Traceback" not in gw.log()

    # an endpoint changed (and a node added beside it): refused whole, a restart needed
    rewrite(gw, nodes=[KEPT, {"address": 77, "stream": "euler"}, {"address": 78}],
            publish={"endpoint": f"tcp://127.0.0.1:{free_port()}"})
    ran = gx2ctl("--config", config, "reload")
    assert ran.status == 1, ran
    assert "publish.endpoint" in ran.stderr and "restart" in ran.stderr, ran
    assert "publish.endpoint" in refusals(gw)[-1]
    assert addresses(gw) == {76, 77}
    assert continuous(sim, 78) == 0 and continuous(sim, 77) == 0xCE

    # then a good one through gx2ctl: what changed, printed
    rewrite(gw, nodes=[KEPT, {"address": 78, "stream": "euler"}])
    ran = gx2ctl("--config", config, "reload")
    assert ran.status == 0, ran
    assert ran.stdout.splitlines() == ["added: 78", "removed: 77"]
    assert addresses(gw) == {76, 78}
    assert continuous(sim, 77) == 0, "the removed node still streams"
    gw.wait_streaming(78)

    # a changed stream is armed again; --json says which
    rewrite(gw, nodes=[KEPT, {"address": 78, "stream": "accel_angrate"}])
    ran = gx2ctl("--config", config, "--json", "reload")
    assert ran.status == 0, ran
    assert json.loads(ran.stdout) == {"added": [], "removed": [], "changed": [78],
                                      "not_stopped": []}
    wait_for(lambda: continuous(sim, 78) == 0xC2, 10, "78 armed with its new stream")
    assert continuous(sim, 76) == 0xC2


def still_pair(simulator, gateway):
    """76 kept and 77 streaming euler, both still (a bias capture needs no motion)."""
    sim = simulator(*(NodeSettings(a, divider=DIVIDER, motion=Motion(yaw_rate=0.0))
                      for a in (76, 77)))
    gw = gateway(sim.path, [KEPT, {"address": 77, "stream": "euler"}])
    gw.wait_streaming(76, 77)
    return sim, gw


def test_a_reload_waits_for_a_capture_on_a_node_it_removes_and_never_for_another(
        simulator, gateway):
    sim, gw = still_pair(simulator, gateway)
    config = str(gw.path)
    long = Running("gx2ctl", "--config", config, "bias", "capture", "76", "--ms", "8000")
    short = Running("gx2ctl", "--config", config, "bias", "capture", "77", "--ms", "2000")
    try:
        wait_for(lambda: {n["node"]: n["state"] for n in gw.status()["nodes"]}
                 == {76: "busy", 77: "busy"}, 10, "both captures under way")
        rewrite(gw, nodes=[KEPT])
        ran = gx2ctl("--config", config, "--timeout", "10", "reload")
        assert ran.status == 0 and ran.stdout.splitlines() == ["removed: 77"], ran
        assert long.proc.poll() is None, "the reload waited for another node's capture"
        assert short.finish(10) == 0, short.stderr  # (ended whole before 77 was removed)
        assert long.finish(15) == 0, long.stderr
    finally:
        long.kill()
        short.kill()
    assert addresses(gw) == {76}
    assert continuous(sim, 77) == 0 and continuous(sim, 76) == 0xC2
    assert [c.arguments["sampling_time"] for c in received(sim, 76, 0xCD)] == [8000]


def test_a_reload_waiting_for_a_capture_says_so_and_refuses_new_operations_on_the_node(
        simulator, gateway):
    sim, gw = still_pair(simulator, gateway)
    config = str(gw.path)
    capture = Running("gx2ctl", "--config", config, "bias", "capture", "77", "--ms", "6000")
    try:
        wait_for(lambda: {n["node"]: n["state"] for n in gw.status()["nodes"]}[77] == "busy",
                 10, "the capture under way")
        rewrite(gw, nodes=[KEPT])
        # the gateway answers in time that the reload waits (exit 3), not a node failure
        ran = gx2ctl("--config", config, "--timeout", "2", "reload")
        assert ran.status == 3 and ran.stdout == "", ran
        assert len(ran.stderr.splitlines()) == 1, ran
        assert "waits for the operation on node 77" in ran.stderr and "log" in ran.stderr
        # a new operation on 77 cannot starve it: refused in one line
        late = gx2ctl("--config", config, "info", "77")
        assert late.status == 1 and len(late.stderr.splitlines()) == 1, late
        assert "a reload is removing node 77" in late.stderr, late
        assert gx2ctl("--config", config, "ping", "76").status == 0
        assert capture.finish(15) == 0, capture.stderr
    finally:
        capture.kill()
    wait_for(lambda: addresses(gw) == {76}, 10, "77 removed once its capture ended")
    assert "waits for the operation on node 77" in gw.log()
    assert [c.arguments["sampling_time"] for c in received(sim, 77, 0xCD)] == [6000]


def test_a_reload_of_a_file_that_cannot_be_read_never_freezes_the_gateway(
        simulator, gateway):
    sim = three_nodes(simulator)
    gw = gateway(sim.path, [KEPT])
    gw.wait_streaming(76)
    gw.path.unlink()
    os.mkfifo(gw.path)  # opening it blocks until someone writes: no one does
    gw.proc.send_signal(signal.SIGHUP)
    started = time.monotonic()
    ran = gx2ctl("--control", gw.config["control"]["endpoint"], "--timeout", "2", "status")
    assert ran.status == 0, ran
    assert time.monotonic() - started < 2
    wait_for(lambda: refusals(gw), 10, "the refusal in the log")
    assert "not read within" in refusals(gw)[-1] and "kept" in refusals(gw)[-1]
    assert addresses(gw) == {76}
    assert gw.terminate()[0] == 0, gw.log()


def test_a_reload_that_names_renames_and_adds_is_seen_in_every_frame_and_the_status(
        simulator, gateway, tmp_path):
    """A reload renames node 76 and adds 77 with a name: the frames Foxglove draws
    (live, and in the recording) are named as the nodes are from then on, never as at
    their first record (a renamed node kept its old name, and one added by a reload was
    ``gx2-77``); status and metrics say the new names."""
    sim = simulator(NodeSettings(76, divider=DIVIDER, motion=SWING),
                    NodeSettings(77, divider=DIVIDER, motion=SWING))
    directory = tmp_path / "recordings"
    left = {"address": 76, "name": "left-wing", "stream": "accel_angrate_orientation"}
    gw = gateway(sim.path, [left], record={"directory": str(directory)},
                 live={"endpoint": f"127.0.0.1:{free_port()}"}, metrics={})
    gw.wait_streaming(76)
    viewer = Viewer(f"ws://{gw.config['live']['endpoint']}")
    try:
        viewer.until(lambda v: "gx2/76/frame" in v.topics(), 10, "76's frame channel")
        viewer.subscribe(viewer.topics()["gx2/76/frame"])
        viewer.until(lambda v: len(v.messages) > 20, 10, "frames of 76")
        rewrite(gw, nodes=[{**left, "name": "right-wing"},
                           {"address": 77, "name": "tail", "stream": "euler"}])
        done = gx2ctl("--control", gw.control_endpoint, "reload")
        assert done.status == 0, done
        gw.wait_streaming(77)
        viewer.until(lambda v: "gx2/77/frame" in v.topics(), 10, "77's frame channel")
        viewer.subscribe(viewer.topics()["gx2/77/frame"])
        viewer.until(lambda v: any(m.topic == "gx2/77/frame" for m in v.messages)
                     and v.messages[-1].payload["child_frame_id"] != "left-wing", 10,
                     "frames of both after the reload")
        viewer.read(0.3)
    finally:
        viewer.close()
    named = [(m.topic, m.payload["child_frame_id"]) for m in viewer.messages]
    assert ("gx2/76/frame", "left-wing") == named[0]
    renamed_at = named.index(("gx2/76/frame", "right-wing"))
    assert set(named[renamed_at:]) == {("gx2/76/frame", "right-wing"),
                                       ("gx2/77/frame", "tail")}
    status = gw.status()
    assert {n["node"]: n["name"] for n in status["nodes"]} == {76: "right-wing", 77: "tail"}
    metrics = wait_for(lambda: (m := _metrics(gw)) and 'name="tail"' in m and m, 5,
                       "the metrics of the new names")
    assert 'name="right-wing"' in metrics and 'name="left-wing"' not in metrics
    assert gw.terminate()[0] == 0, gw.log()

    frames: dict[str, list[str]] = {}
    for topic, message, _ in recorded(directory):
        if topic.endswith("/frame"):
            frames.setdefault(topic, []).append(json.loads(message.data)["child_frame_id"])
    seen = frames["gx2/76/frame"]
    changed = seen.index("right-wing")
    assert changed > 0 and set(seen[:changed]) == {"left-wing"}
    assert set(seen[changed:]) == {"right-wing"}
    assert frames["gx2/77/frame"] and set(frames["gx2/77/frame"]) == {"tail"}
