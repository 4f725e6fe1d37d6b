"""Watching the gateway run, through a real pty and real sockets: the metrics endpoint
scraped over HTTP and read with prometheus-client's own parser, and each node's health
as status, the heartbeat, the metrics and ``gx2ctl status --check`` show it while the
simulated radio loses 10% of one node's packets and then recovers."""

from __future__ import annotations

import re
import time
import urllib.request
from typing import Any

from prometheus_client.parser import text_string_to_metric_families

from gateway.sim.base_station import RadioLink
from gateway.sim.node import NodeSettings
from tests.helpers.ports import free_port
from tests.helpers.processes import EXIT, STARVED, gx2ctl
from tests.helpers.waiting import wait_for

SCRAPE_EVERY = 0.1
"""The least time between two scrapes while a test waits for a metric to change."""


class Scraper:
    def __init__(self, endpoint: str) -> None:
        self.url = f"http://{endpoint}/metrics"
        self.scrapes = 0
        self._last: tuple[float, dict[str, dict[tuple, float]]] | None = None

    def __call__(self) -> dict[str, dict[tuple, float]]:
        """metric name (counters without _total) -> {sorted labels: value}."""
        if self._last is not None and time.monotonic() - self._last[0] < SCRAPE_EVERY:
            return self._last[1]
        with urllib.request.urlopen(self.url, timeout=5) as reply:
            text = reply.read().decode()
        self.scrapes += 1
        got = {family.name: {tuple(sorted(s.labels.items())): s.value
                             for s in family.samples if not s.name.endswith("_created")}
               for family in text_string_to_metric_families(text)}
        self._last = (time.monotonic(), got)
        return got

    def value(self, name: str, **labels: str) -> float | None:
        return self().get(name, {}).get(tuple(sorted(labels.items())))


def test_metrics_count_as_records_flow_and_the_link_falls_when_unplugged(simulator,
                                                                          gateway) -> None:
    sim = simulator(NodeSettings(76), NodeSettings(77))
    metrics = f"127.0.0.1:{free_port()}"
    gw = gateway(sim.path, [{"address": 76, "name": "left", "stream": "accel_angrate"},
                            {"address": 77, "stream": "euler"}], metrics={"endpoint": metrics})
    gw.wait_streaming(76, 77)
    scrape = Scraper(metrics)
    records = {"node": "76", "record": "accel_angrate"}
    first = wait_for(lambda: scrape.value("gx2_records_published", **records), 5,
                     "node 76's records counted")
    received = scrape.value("gx2_node_received", node="77")
    wait_for(lambda: scrape.value("gx2_records_published", **records) >= first + 100, 5,
             "the count to grow as records flow")
    assert scrape.value("gx2_node_received", node="77") > received
    wait_for(lambda: scrape.value("gx2_node_rate_hz", node="77") > 50, 5,
             "node 77's rate measured (a window of 2 s)")
    got = scrape()
    assert got["gx2_link_up"] == {(): 1.0}
    assert -128 <= got["gx2_node_rssi_dbm"][(("node", "76"),)] < 0
    assert got["gx2_node_info"][(("name", "left"), ("node", "76"), ("station", "station1"))] == 1.0
    assert got["gx2_node_state"][(("node", "77"), ("state", "streaming"))] == 1.0
    status = gw.status()  # the same counts as status, give or take the records since
    assert status["link"]["state"] == "up"

    sim.unplug(duration=2.0)
    wait_for(lambda: scrape.value("gx2_link_up") == 0.0, 5, "gx2_link_up to fall")
    assert scrape.value("gx2_node_state", node="76", state="link down") == 1.0
    wait_for(lambda: scrape.value("gx2_link_up") == 1.0, 10, "gx2_link_up back")
    wait_for(lambda: scrape.value("gx2_link_reconnects") == 1.0, 5, "the reconnect counted")
    status, seconds = gw.terminate()  # (the metrics server stops within the exit promise)
    assert status == 0 and seconds < EXIT + STARVED, (status, seconds)


def node_health(report: dict[str, Any], node: int) -> tuple[str, list[str]]:
    entry = next(n for n in report["nodes"] if n["node"] == node)
    return entry["health"], entry["reasons"]


def test_health_warns_while_the_radio_loses_10_percent_and_recovers_after(simulator,
                                                                           gateway) -> None:
    sim = simulator(NodeSettings(76), NodeSettings(77))
    metrics = f"127.0.0.1:{free_port()}"
    gw = gateway(sim.path, [{"address": 76, "stream": "accel_angrate"},
                            {"address": 77, "stream": "accel_angrate"}],
                 metrics={"endpoint": metrics},
                 # (a short window, and a rate judged to 25%: this test's subject is the
                 # radio loss; at 5%, 0.2 s of the simulator starved for the CPU in 4 s
                 # made both nodes WARN, at 6 test processes on 2 cores)
                 health={"window_s": 4.0, "settle_s": 3.0, "rate_under_percent": 25.0})
    scrape = Scraper(metrics)
    gw.wait_streaming(76, 77)

    def judged_ok(node: dict[str, Any]) -> bool:  # (its rate and clock judged too)
        return (node["health"] == "OK" and node["rate_hz"] > 90
                and node["recent"]["seconds"] >= 3.5 and node["clock"]["locked"])
    wait_for(lambda: all(judged_ok(n) for n in gw.status()["nodes"]), 15,
             "both nodes streaming, judged and OK")
    check = gx2ctl("--config", str(gw.path), "status", "--check")
    assert check.status == 0, check

    before = len(gw.log())  # (each line's first second said its clock not locked)
    sim.call(lambda station, now: setattr(station.radio[77], "data_loss", 0.10))

    def radio_loss_warned() -> bool:
        level, reasons = node_health(gw.status(), 77)
        return level == "WARN" and any(r.startswith("radio loss ") for r in reasons)
    wait_for(radio_loss_warned, 10, "node 77 to warn of its radio loss")
    assert node_health(gw.status(), 76) == ("OK", [])  # the other node is unaffected
    wait_for(lambda: scrape.value("gx2_node_health", node="77") == 1.0, 5,
             "gx2_node_health of 77 to say WARN")
    heartbeat = gw.subscribe("gx2/gateway/status").until(
        lambda m: m and node_health(m[-1][1], 77)[0] == "WARN", 5, "a heartbeat with it")
    assert node_health(heartbeat[-1][1], 76)[0] == "OK"
    check = gx2ctl("--config", str(gw.path), "status", "--check")
    assert check.status == 1, check
    assert check.stderr.strip() == "gx2ctl: 1 of 2 nodes not OK: 77 WARN", check
    assert re.search(r"^77 WARN: .*radio loss \d+\.\d% in \d s", check.stdout, re.M), check

    sim.call(lambda station, now: setattr(station.radio[77], "data_loss", 0.0))
    wait_for(lambda: node_health(gw.status(), 77) == ("OK", []), 15,
             "node 77 OK again once the lossy seconds have left the window")
    assert gx2ctl("--config", str(gw.path), "status", "--check").status == 0
    assert "node 77 health OK -> WARN: " in gw.log()[before:]
    wait_for(lambda: "node 77 health WARN -> OK" in gw.log()[before:], 3, "the recovery logged")
    assert "node 76 health" not in gw.log()[before:]


def test_a_node_out_of_range_stays_an_error_through_its_retries_until_it_streams(
        simulator, gateway) -> None:
    sim = simulator(NodeSettings(76), NodeSettings(95),
                    radio={95: RadioLink(in_range=False)})
    gw = gateway(sim.path, [{"address": 76, "stream": "accel_angrate"},
                            {"address": 95, "stream": "euler"}])
    seen: list[tuple[str, str, list[str]]] = []

    def through_a_retry() -> bool:
        node = next(n for n in gw.status()["nodes"] if n["node"] == 95)
        seen.append((node["state"], node["health"], node["reasons"]))
        states = [state for state, _, _ in seen]
        return "unreachable" in states and "arming" in states[states.index("unreachable"):]
    wait_for(through_a_retry, 20, "node 95 to fail and be armed again")
    failed = [entry for entry in seen if entry[0] in ("unreachable", "arming")]
    first = next(i for i, entry in enumerate(failed) if entry[0] == "unreachable")
    assert all(health == "ERROR" and reasons == ["unreachable"]
               for _, health, reasons in failed[first:]), failed

    sim.call(lambda station, now: setattr(station.radio[95], "in_range", True))
    gw.wait_streaming(95, timeout=40)  # (its next try, after the backoff)
    # streaming, it is out of its failure at once; its clock locks within its line's
    # first second (said "clock not locked" meanwhile)
    assert node_health(gw.status(), 95)[0] != "ERROR"
    wait_for(lambda: node_health(gw.status(), 95) == ("OK", []), 10, "node 95 OK")
