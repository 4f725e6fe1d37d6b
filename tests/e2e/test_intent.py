"""What a node keeps doing: its configured stream, until an operator's ``start`` or
``stop`` replaces it, through reboots and reconnects; and a node streaming on its own
is shown as streaming.

Found by a new user: after ``start 77 accel_angrate`` and a reboot of node 77 the
gateway re-armed the configured ``euler``; ``stop 95`` on an unreachable node said
"stopped" and the gateway went on trying to arm it; a node that auto-starts its stream
from EEPROM showed as ``polled`` / ``-``. Only the console scripts and the control
protocol are used on the gateway's side, so ``GX2_BIN`` runs these against another
version.
"""

from __future__ import annotations

from gateway.sim.base_station import RadioLink
from gateway.sim.node import NodeSettings
from tests.helpers.processes import gx2ctl
from tests.helpers.simulated import commands_to, continuous
from tests.helpers.waiting import wait_for

ACCEL_ANGRATE, EULER = 0xC2, 0xCE
WATCHED = 4.0
"""Seconds of watching for commands that must not come: longer than the first three
backoffs of a node being retried (0.5, 1 and 2 s)."""


def test_an_operators_start_outlives_a_reboot(simulator, gateway):
    sim = simulator(NodeSettings(77))
    gw = gateway(sim.path, [{"address": 77, "stream": "euler"}])
    gw.wait_streaming(77)
    assert continuous(sim, 77) == EULER
    ran = gx2ctl("--config", str(gw.path), "start", "77", "accel_angrate")
    assert ran.status == 0, ran

    sim.reboot(77)  # a battery swap: the node comes back streaming nothing
    wait_for(lambda: gw.node_status(77)["reboots"] == 1, 10, "the reboot to be seen")
    wait_for(lambda: continuous(sim, 77) != 0, 10, "node 77 to be armed again")
    assert continuous(sim, 77) == ACCEL_ANGRATE, "the configured stream came back instead"
    gw.wait_streaming(77)
    node = gw.node_status(77)
    assert node["record"] == "accel_angrate", node
    assert (node["configured"], node["desired"]) == ("euler", "accel_angrate"), node


def test_an_operators_stop_of_an_unreachable_node_ends_the_retries(simulator, gateway):
    sim = simulator(NodeSettings(76), NodeSettings(95),
                    radio={95: RadioLink(in_range=False)})
    gw = gateway(sim.path, [{"address": 76}, {"address": 95, "stream": "euler"}])
    wait_for(lambda: commands_to(sim, 95) >= 3, 10, "the gateway to retry node 95")
    ran = gx2ctl("--config", str(gw.path), "stop", "95")
    assert ran.status == 1 and "not confirmed: no answer" in ran.stderr, ran  # (issue 21)
    sent = commands_to(sim, 95)
    ping = gw.control.result("ping", nodes=[76])  # the line works meanwhile
    assert ping["nodes"][0]["answered"]
    assert quiet_for_a_while(sim, 95, sent), "the gateway went on sending to node 95"
    node = gw.node_status(95)
    assert node["desired"] == "off" and node["state"] != "arming", node


def quiet_for_a_while(sim, node: int, sent: int) -> bool:
    """True if no command for ``node`` arrives during WATCHED seconds (watching for
    an absence: the bounded window is the test)."""
    try:
        wait_for(lambda: commands_to(sim, node) > sent, WATCHED, "a command to the node")
    except AssertionError:
        return True
    return False


def test_a_node_streaming_on_its_own_shows_as_streaming(simulator, gateway):
    """EEPROM auto-start, no ``stream:`` configured: status shows the record and rate;
    after a reboot it streams again on its own and still shows so; an operator's stop
    is kept through the next reboot, although the node starts streaming again."""
    sim = simulator(NodeSettings(76, stream="euler"))
    gw = gateway(sim.path, [{"address": 76}])

    def streaming_euler() -> bool:
        node = gw.node_status(76)
        return node["state"] == "streaming" and node["record"] == "euler" \
            and node["rate_hz"] > 0
    wait_for(streaming_euler, 10, "node 76 to show as streaming euler")
    wait_for(lambda: 50 <= gw.node_status(76)["rate_hz"] <= 150, 10, "a rate near 100 Hz")
    assert gw.node_status(76)["divider"] == 512

    sim.reboot(76)
    wait_for(lambda: gw.node_status(76)["reboots"] == 1, 10, "the reboot to be seen")
    wait_for(streaming_euler, 10, "node 76 to show as streaming euler again")

    ran = gx2ctl("--config", str(gw.path), "stop", "76")
    assert ran.status == 0, ran
    sim.reboot(76)  # auto-start: it streams again, which the operator did not want
    wait_for(lambda: gw.node_status(76)["reboots"] == 2, 10, "the second reboot")
    wait_for(lambda: continuous(sim, 76) == 0 and gw.node_status(76)["state"] == "polled",
             10, "the gateway to stop node 76 again")
    assert gw.node_status(76)["desired"] == "off"
