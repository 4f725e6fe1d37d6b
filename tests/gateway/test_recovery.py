"""Recovery through the real pty (issue 5): the base station unplugged and back, and a
node rebooting, while the gateway keeps running."""

from __future__ import annotations

import time

from harness import wait_for

from gateway.sim.node import NodeSettings


def link_state(gw) -> str:
    reply = gw.control.try_call("status", timeout=1.0)
    assert reply is not None, "the control endpoint stopped answering"
    return reply["result"]["link"]["state"]


def test_unplug_and_return_re_arms_the_streams(simulator, gateway):
    sim = simulator(NodeSettings(76), NodeSettings(77))
    gw = gateway(sim.path, [{"address": 76, "stream": "accel_angrate"},
                            {"address": 77, "stream": "euler"}])
    gw.wait_streaming(76, 77)
    sub = gw.subscribe("gx2/76/", "gx2/77/", "gx2/gateway/")
    sub.until(lambda m: len(m) > 20, 5, "records before the unplug")

    sim.unplug(duration=1.0)
    unplugged = time.monotonic()
    wait_for(lambda: link_state(gw) == "down", 5, "status to say the link is down")
    sim.call(lambda station, now: [node.power_up(now) for node in station.nodes.values()])
    # (a base station re-plugged is a fresh USB device, and here the nodes lost power
    # too: nothing streams until the gateway arms them again)
    wait_for(lambda: link_state(gw) == "up", 10, "the port to be reopened")
    reconnect = time.monotonic() - unplugged
    gw.wait_streaming(76, 77, timeout=10)
    mark = len(sub.messages)
    sub.until(lambda m: {p.get("node") for _, p in m[mark:]} >= {76, 77}, 5,
              "both streams back")
    assert reconnect < 1.0 + 1.5  # the outage plus at most one 1 s reopen step (+ slack)
    status = gw.status()
    assert status["link"]["reconnects"] == 1
    down = [p for t, p in sub.messages if t == "gx2/gateway/status"
            and p["link"]["state"] == "down"]
    assert down, "subscribers were told the link went down"
    for node in (76, 77):
        seqs = [p["seq"] for _, p in sub.messages if p.get("node") == node]
        assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)  # seq never restarts
    assert gw.proc.poll() is None


def test_node_reboot_is_detected_and_its_stream_re_armed(simulator, gateway):
    sim = simulator(NodeSettings(76))
    gw = gateway(sim.path, [{"address": 76, "stream": "euler"}])
    gw.wait_streaming(76)
    sub = gw.subscribe("gx2/76/")
    sub.until(lambda m: len(m) > 10, 5, "records before the reboot")
    sim.reboot(76)  # a discovery packet, the timer restarts, the stream is off
    wait_for(lambda: gw.node_status(76)["reboots"] == 1, 5, "the reboot to be counted")
    gw.wait_streaming(76, timeout=10)
    mark = len(sub.messages)
    records = sub.until(lambda m: len(m) > mark + 10, 5, "the stream back")[mark:]
    times = [p["device_time"] for _, p in sub.messages if "device_time" in p]
    assert times == sorted(times), "device_time went back across the reboot"
    timed = [p for _, p in records if "timer" in p]  # (re-arming reads 0xE5: untimed)
    assert timed and all(p["timer"] < 10 * 19_660_800 for p in timed)  # the new power-up
    assert gw.node_status(76)["reboots"] == 1  # counted once (discovery and timer)
