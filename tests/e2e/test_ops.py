"""The control ops through a real pty and real sockets: start, poll, rate, info,
EEPROM reads and writes (and their refusal), and a repeated request id."""

from __future__ import annotations

import time
from pathlib import Path

import msgpack

from aspp.commands import EEPROM_DIVIDER
from gateway.sim.node import FIRMWARE_VERSION, NodeSettings
from tests.helpers.simulated import check_payload, continuous, received

REPO = Path(__file__).resolve().parents[2]
CLI_TIMEOUT = 15.0
"""Seconds a `gx2-gateway` run with a bad configuration may take before it counts as hung."""


# -- 4. start, poll, rate, info, eeprom read -------------------------------------------------------

def test_start_poll_rate_info_eeprom_read(simulator, gateway):
    sim = simulator(NodeSettings(76))
    gw = gateway(sim.path, [{"address": 76}], control={"allow_eeprom_write": True})
    sub = gw.subscribe("gx2/76/")
    assert gw.node_status(76)["state"] == "polled"

    started = gw.control.result("start", node=76, record="euler")
    assert started["node"] == 76 and started["record"] == "euler"
    assert started["attempts"] >= 1
    assert continuous(sim, 76) == 0xCE
    messages = sub.until(lambda m: any(t == "gx2/76/euler" for t, _ in m), 5,
                         "an euler record")
    topic, payload = next((t, p) for t, p in messages if t == "gx2/76/euler")
    check_payload(topic, payload, 76, "euler", 0xCE)
    for field in ("roll", "pitch", "yaw", "device_time"):
        assert isinstance(payload[field], float), (field, payload)
    assert isinstance(payload["timer"], int)
    node = gw.node_status(76)
    assert (node["state"], node["record"]) == ("streaming", "euler")

    polled = gw.control.result("poll", node=76, record="accel_angrate")  # while streaming
    check_payload("gx2/76/accel_angrate", polled, 76, "accel_angrate", 0xC2)
    assert len(polled["accel"]) == 3 and len(polled["ang_rate"]) == 3
    sub.until(lambda m: any(t == "gx2/76/accel_angrate" and p["seq"] == polled["seq"]
                            for t, p in m), 3, "the polled reply to be published")

    rate = gw.control.result("rate", node=76, hz=50)
    changed = time.time()
    assert rate == {"node": 76, "hz": 50.0, "divider": 1024}
    assert sim.call(lambda station, now: station.nodes[76].eeprom[EEPROM_DIVIDER]) == 1024
    log = sim.call(lambda station, now: list(station.nodes[76].log.commands))
    writes = [i for i, c in enumerate(log) if c.code == 0xE4]
    assert [(log[i].arguments["address"], log[i].arguments["value"]) for i in writes] == \
        [(EEPROM_DIVIDER, 1024)]
    assert any(c.code == 0xE5 and c.arguments["address"] == EEPROM_DIVIDER
               for c in log[writes[0]:]), "the written divider was not read back"
    assert gw.node_status(76)["divider"] == 1024

    begin, end = changed + 0.2, changed + 1.4
    sub.until(lambda m: any(p.get("host_time", 0) > end + 0.1 for _, p in m), 5,
              "records at the new rate")
    window = [p for t, p in sub.messages
              if t == "gx2/76/euler" and begin <= p["host_time"] <= end]
    # arrival times jitter with scheduling (a stall at either end of the window moves
    # records across it); the device timer below is exact
    assert 45 <= len(window) <= 75, f"{len(window)} records in 1.2 s, expected about 60"
    device_rate = (len(window) - 1) / (window[-1]["device_time"] - window[0]["device_time"])
    assert abs(device_rate - 50) < 1, device_rate

    info = gw.control.result("info", node=76)
    assert info["node"] == 76
    assert info["firmware"] == FIRMWARE_VERSION == 2113
    assert info["model_name"] == "Inertia-Link"
    assert info["model_number"] == "6226-0001"
    assert info["serial_number"] == "4200-0076"
    assert info["options"] == "Wireless"

    read = gw.control.result("eeprom_read", node=76, address=EEPROM_DIVIDER)
    assert read == {"node": 76, "address": EEPROM_DIVIDER, "value": 1024}


# -- 5. EEPROM writes need allow_eeprom_write ------------------------------------------------------

def test_eeprom_writes_refused_unless_allowed(simulator, gateway):
    sim = simulator(NodeSettings(76), first_write_failure_rate=1.0)
    gw = gateway(sim.path, [{"address": 76}])  # allow_eeprom_write: false by default
    for op, fields in (("eeprom_write", {"address": EEPROM_DIVIDER, "value": 1024}),
                       ("rate", {"hz": 50})):
        reply = gw.control.call(op, node=76, **fields)
        assert reply["ok"] is False, reply
        assert reply["error"]["kind"] == "refused", reply
        assert "allow_eeprom_write" in reply["error"]["message"], reply
    # a read still works, and once it is answered any write sent before it has arrived
    read = gw.control.result("eeprom_read", node=76, address=EEPROM_DIVIDER)
    assert read["value"] == 512
    assert received(sim, 76, 0xE4) == []
    status, _ = gw.terminate()
    assert status == 0

    gw = gateway(sim.path, [{"address": 76}], control={"allow_eeprom_write": True})
    result = gw.control.result("eeprom_write", node=76, address=EEPROM_DIVIDER, value=1024)
    assert result == {"node": 76, "address": EEPROM_DIVIDER, "value": 1024, "attempts": 2}
    assert len(received(sim, 76, 0xE4)) == 2  # the first write after power-up failed
    read = gw.control.result("eeprom_read", node=76, address=EEPROM_DIVIDER)
    assert read["value"] == 1024
    assert sim.call(lambda station, now: station.nodes[76].eeprom[EEPROM_DIVIDER]) == 1024


# -- 6. a repeated request id runs once ------------------------------------------------------------

def test_repeated_request_id_runs_once(simulator, gateway):
    sim = simulator(NodeSettings(76), first_write_failure_rate=0.0)
    gw = gateway(sim.path, [{"address": 76}], control={"allow_eeprom_write": True})
    request = msgpack.packb({"id": "write-1", "op": "eeprom_write", "node": 76,
                             "address": EEPROM_DIVIDER, "value": 1024})
    gw.control.send_raw(b"", request)
    gw.control.send_raw(b"", request)  # the retry of a client that gave up too early
    first, second = gw.control.receive(10), gw.control.receive(10)
    assert first is not None and second is not None, (first, second)
    assert first["ok"], first
    assert first["result"] == {"node": 76, "address": EEPROM_DIVIDER, "value": 1024,
                               "attempts": 1}
    assert second == first
    assert gw.control.receive(0.3) is None, "a third reply to two requests"
    assert len(received(sim, 76, 0xE4)) == 1

    gw.control.send_raw(b"", request)  # again, after it finished: the remembered answer
    assert gw.control.receive(10) == first
    assert len(received(sim, 76, 0xE4)) == 1

    other = gw.control.result("eeprom_write", node=76, address=EEPROM_DIVIDER, value=1024)
    assert other["value"] == 1024
    assert len(received(sim, 76, 0xE4)) == 2  # a new id is a new write




def test_eeprom_writes_only_to_documented_words_unless_overridden(simulator, gateway):
    """Even with writes allowed, a word the reference does not document is refused (a
    wrong word can break a node's calibration) until the override is configured."""
    sim = simulator(NodeSettings(76))
    gw = gateway(sim.path, [{"address": 76}], control={"allow_eeprom_write": True})
    reply = gw.control.call("eeprom_write", node=76, address=0x0100, value=7)
    assert reply["ok"] is False and reply["error"]["kind"] == "refused", reply
    assert "allow_any_eeprom_address" in reply["error"]["message"]
    assert not [c for c in sim.node(76).log.commands if c.code == 0xE4]
    assert gw.control.result("eeprom_write", node=76, address=0xFCA6, value=0x80C2)
    gw.terminate()
    sim.stop()  # the next simulator takes the same link path
    sim2 = simulator(NodeSettings(77))
    gw2 = gateway(sim2.path, [{"address": 77}],
                  control={"allow_eeprom_write": True, "allow_any_eeprom_address": True})
    assert gw2.control.result("eeprom_write", node=77, address=0x0100, value=7)["value"] == 7
