"""Every request is answered within the client's ``--timeout``, whatever the gateway's
own background work is doing: a node that does not answer is exit 1, never 3.

Found by a new user: with node 95 configured to stream but out of range, ``info 95``,
``poll 95 euler`` and ``eeprom read 95 0xFCA2`` exited 3 ("is gx2-gateway running?")
after 5 s, and ``ping 95`` took 4 s, each waiting behind the gateway's own retries to
arm node 95. These tests use only the console scripts and the control protocol, so
``GX2_BIN=<an older installation's bin>`` runs them against another version.
"""

from __future__ import annotations

import time

import msgpack
import pytest

from tests.helpers.processes import gx2ctl
from tests.helpers.waiting import wait_for

NODES = [{"address": 76, "stream": "euler"}, {"address": 95, "stream": "euler"}]
OUT_OF_RANGE = "sim://?out_of_range=95"
PING_WITHIN = 1.5
"""Seconds a ping of a node that does not answer may take: the base station answers
0x21 after 30 ms; the rest is the line and a loaded machine. (It took 4 s.)"""


def retrying(gw) -> None:
    """Wait until the gateway's background work on node 95 is under way."""
    wait_for(lambda: gw.node_status(95)["state"] in ("arming", "unreachable"), 10,
             "the gateway to be trying to arm node 95")


@pytest.mark.parametrize(("timeout", "command"), [
    ("5", ["info", "95"]),
    ("5", ["poll", "95", "euler"]),
    ("5", ["eeprom", "read", "95", "0xFCA2"]),
    ("2", ["info", "95"]),  # five requests to the node: more than 2 s of retries
])
def test_a_node_that_does_not_answer_is_exit_1_within_the_timeout(gateway, timeout,
                                                                    command):
    gw = gateway(OUT_OF_RANGE, NODES)
    retrying(gw)
    ran = gx2ctl("--config", str(gw.path), "--timeout", timeout, *command)
    assert ran.status == 1, ran
    assert "95" in ran.stderr and len(ran.stderr.splitlines()) == 1, ran
    assert gw.node_status(76)["state"] == "streaming"


def test_a_ping_does_not_wait_behind_background_retries(gateway):
    gw = gateway(OUT_OF_RANGE, NODES)
    retrying(gw)
    for _ in range(3):
        start = time.monotonic()
        reply = gw.control.call("ping", nodes=[95, 76])
        took = time.monotonic() - start
        assert reply["ok"], reply
        assert reply["result"]["nodes"] == [{"node": 95, "answered": False},
                                            {"node": 76, "answered": True}]
        assert took < PING_WITHIN, f"ping took {took:.2f} s"


def test_the_gateway_answers_before_the_requests_own_timeout(gateway):
    """A request that says how long its client waits is answered before then, with the
    node's failure, even when the node's retries would take longer."""
    gw = gateway(OUT_OF_RANGE, NODES)
    retrying(gw)
    start = time.monotonic()
    gw.control.send_raw(b"", msgpack.packb({"id": "in-time", "op": "info", "node": 95,
                                            "timeout": 1.0}))
    reply = gw.control.receive(10)
    took = time.monotonic() - start
    assert reply is not None and reply["id"] == "in-time", reply
    assert reply["ok"] is False and reply["error"]["kind"] == "node", reply
    assert "95" in reply["error"]["message"]
    assert took < 1.0, f"answered after {took:.2f} s, past the request's 1 s"
