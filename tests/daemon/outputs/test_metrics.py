"""The metrics endpoint on its own: a status report in, Prometheus text out over real
HTTP, read back with prometheus-client's own parser (the end-to-end test scrapes the
running gateway)."""

from __future__ import annotations

import socket
import urllib.request
from collections.abc import Iterator
from typing import Any

import pytest
from prometheus_client.parser import text_string_to_metric_families

from gateway.common.endpoints import host_port
from gateway.daemon.outputs.metrics import MetricsServer
from tests.helpers.ports import free_port

CONTRACT = {
    "gx2_link_up": ("gauge", ()),
    "gx2_link_reconnects": ("counter", ()),
    "gx2_link_discarded_bytes": ("counter", ("reason",)),
    "gx2_records_published": ("counter", ("node", "record")),
    "gx2_node_lost_radio": ("counter", ("node",)),
    "gx2_node_lost_gateway": ("counter", ("node",)),
    "gx2_node_lost_station_down": ("counter", ("node",)),
    "gx2_node_reboots": ("counter", ("node",)),
    "gx2_node_rssi_dbm": ("gauge", ("node",)),
    "gx2_node_lqi": ("gauge", ("node",)),
    "gx2_node_rate_hz": ("gauge", ("node",)),
    "gx2_node_clock_drift_ppm": ("gauge", ("node",)),
}
"""The interface's metrics: (type, labels). The parser names a counter without _total."""


LINK = {"state": "up", "reconnects": 2, "bytes_read": 123_456, "bytes_per_s": 9500.0,
        "line_bytes_per_s": 11520.0, "discarded": {"garbage": 40, "truncated": 2},
        "unknown_node_packets": 3, "bad_records": 0, "retries": 4, "failures": 1}
HEARD = [{"address": 81, "record": "accel_angrate", "rate_hz": 100.0, "rssi": -61.0,
          "lqi": 190.0, "packets": 3000, "last_heard": 1_800_000_099.9},
         {"address": 82, "record": None, "rate_hz": None, "rssi": -50.0, "lqi": 200.0,
          "packets": 1, "last_heard": 1_800_000_050.0}]
"""Two nodes the station heard that are not configured: 81 streams, 82 powered up."""


def report(**changes: Any) -> dict[str, Any]:
    """A status report as the gateway makes it: node 76 streaming, 95 never heard; 81
    and 82 heard, not configured."""
    base: dict[str, Any] = {
        "gateway": {"version": "1.2.3", "uptime": 100.0, "time": 1_800_000_100.0,
                    "published": 5000, "publish_failures": 0, "control_requests": 7,
                    "control_rejected": 1, "curve_denied": 0, "health": "OK",
                    "reasons": []},
        "link": LINK,
        "stations": [{**LINK, "name": "station1", "nodes": [76, 95], "heard": HEARD}],
        "nodes": [
            {"node": 76, "name": "left-wing", "station": "station1", "state": "streaming",
             "packets": 4990,
             "lost_radio": 10, "lost_gateway": 0, "reboots": 1, "silences": 0, "rssi": -44,
             "lqi": 201, "rate_hz": 99.5, "expected_hz": 100.0, "last_seen": 1_800_000_099.9,
             "clock": {"drift_ppm": -12.5, "locked": True, "floor_age_s": 41.5},
             "health": "WARN",
             "by_record": {"accel_angrate": 4980, "eeprom_read": 10}},
            {"node": 95, "name": None, "station": "station1", "state": "unreachable",
             "packets": 0, "lost_radio": 0,
             "lost_gateway": 0, "reboots": 0, "silences": 0, "rssi": None, "lqi": None,
             "rate_hz": 0.0, "expected_hz": None, "last_seen": None, "clock": None,
             "health": "ERROR", "by_record": {}},
        ],
        "recording": None,
        "outputs": {"live": {"take_failures": 2}},
    }
    base.update(changes)
    return base


@pytest.fixture
def server() -> Iterator[MetricsServer]:
    metrics = MetricsServer(f"127.0.0.1:{free_port()}")
    yield metrics
    metrics.close()


def scrape(server: MetricsServer) -> dict[str, Any]:
    """name -> the parsed family, from a real GET /metrics."""
    with urllib.request.urlopen(f"http://{server.endpoint}/metrics", timeout=5) as reply:
        assert reply.status == 200
        assert reply.headers["Content-Type"].startswith("text/plain")
        text = reply.read().decode()
    return {family.name: family for family in text_string_to_metric_families(text)}


def values(family: Any) -> dict[tuple[tuple[str, str], ...], float]:
    return {tuple(sorted(s.labels.items())): s.value for s in family.samples
            if not s.name.endswith("_created")}


def test_every_metric_of_the_interface_is_served_with_its_type_and_labels(server) -> None:
    server.report(report())
    families = scrape(server)
    for name, (kind, labels) in CONTRACT.items():
        assert name in families, f"{name} is not served"
        family = families[name]
        assert family.type == kind, name
        for sample in family.samples:
            assert tuple(sorted(sample.labels)) == tuple(sorted(labels)), (name, sample)


def test_the_values_are_the_reports(server) -> None:
    server.report(report())
    got = {name: values(family) for name, family in scrape(server).items()}
    assert got["gx2_link_up"] == {(): 1.0}
    assert got["gx2_link_reconnects"] == {(): 2.0}
    assert got["gx2_link_discarded_bytes"] == {(("reason", "garbage"),): 40.0,
                                               (("reason", "truncated"),): 2.0}
    assert got["gx2_records_published"] == {
        (("node", "76"), ("record", "accel_angrate")): 4980.0,
        (("node", "76"), ("record", "eeprom_read")): 10.0}
    assert got["gx2_node_lost_radio"] == {(("node", "76"),): 10.0, (("node", "95"),): 0.0}
    # a value the node does not have yet is no sample at all, never a made-up 0
    assert got["gx2_node_rssi_dbm"] == {(("node", "76"),): -44.0}
    assert got["gx2_node_lqi"] == {(("node", "76"),): 201.0}
    assert got["gx2_node_clock_drift_ppm"] == {(("node", "76"),): -12.5}
    assert got["gx2_node_clock_floor_age_seconds"] == {(("node", "76"),): 41.5}
    assert got["gx2_node_rate_hz"] == {(("node", "76"),): 99.5, (("node", "95"),): 0.0}
    assert got["gx2_node_health"] == {(("node", "76"),): 1.0, (("node", "95"),): 2.0}
    assert got["gx2_node_state"][(("node", "95"), ("state", "unreachable"))] == 1.0
    assert sum(got["gx2_node_state"].values()) == 2.0  # one state a node
    assert got["gx2_node_info"] == {
        (("name", "left-wing"), ("node", "76"), ("station", "station1")): 1.0,
        (("name", ""), ("node", "95"), ("station", "station1")): 1.0}
    assert got["gx2_gateway_start_time_seconds"] == {(): 1_800_000_000.0}
    assert got["gx2_output_take_failures"] == {(("output", "live"),): 2.0}
    assert "process_cpu_seconds" in got  # the gateway's own CPU and memory


def test_each_station_counts_the_nodes_it_heard_not_configured_and_those_streaming(
        server) -> None:
    server.report(report())
    got = {name: values(family) for name, family in scrape(server).items()}
    assert got["gx2_station_heard_nodes"] == {(("station", "station1"),): 2.0}
    assert got["gx2_station_heard_streaming_nodes"] == {(("station", "station1"),): 1.0}
    # several: one series each, by name; a station that heard none says 0
    stations = [{**LINK, "name": "north", "heard": HEARD[1:]},
                {**LINK, "name": "south", "heard": []}]
    server.report(report(stations=stations))
    got = {name: values(family) for name, family in scrape(server).items()}
    assert got["gx2_station_heard_nodes"] == {(("station", "north"),): 1.0,
                                              (("station", "south"),): 0.0}
    assert got["gx2_station_heard_streaming_nodes"] == {(("station", "north"),): 0.0,
                                                        (("station", "south"),): 0.0}


def test_the_link_down_is_a_zero_and_recording_counters_appear_when_it_records(
        server) -> None:
    server.report(report(link={"state": "down"}, recording={"written": 9, "dropped": 2,
                                                            "errors": 1, "bytes": 12_345}))
    got = {name: values(family) for name, family in scrape(server).items()}
    assert got["gx2_link_up"] == {(): 0.0}
    assert got["gx2_recording_dropped"] == {(): 2.0}
    assert got["gx2_recording_bytes"] == {(): 12_345.0}
    assert got["gx2_gateway_health"] == {(): 0.0}
    assert "gx2_lsl_dropped" not in got  # (no lsl: configured)


def test_the_lsl_counters_appear_with_lsl(server) -> None:
    server.report(report(lsl={"streams": ["gx2-76-euler"], "pushed": 500, "dropped": 3}))
    got = {name: values(family) for name, family in scrape(server).items()}
    assert got["gx2_lsl_pushed"] == {(): 500.0}
    assert got["gx2_lsl_dropped"] == {(): 3.0}


@pytest.mark.parametrize(("health", "value"), [("OK", 0.0), ("WARN", 1.0), ("ERROR", 2.0)])
def test_the_gateways_own_health_is_a_gauge_absent_from_a_gateway_without_one(
        server, health: str, value: float) -> None:
    base = report()
    server.report({**base, "gateway": {**base["gateway"], "health": health,
                                       "reasons": ["recording failed: Disk full"]}})
    assert values(scrape(server)["gx2_gateway_health"]) == {(): value}
    server.report({**base, "gateway": {"version": "0.9", "time": 1.0}})
    assert "gx2_gateway_health" not in scrape(server)


def test_a_report_of_another_shape_loses_only_what_it_lacks(server) -> None:
    odd = report(link={"state": "up", "reconnects": "two", "discarded": [1]},
                 nodes=[{"node": 76, "rssi": float("nan"), "lqi": True, "rate_hz": 50},
                        {"name": "no address"}, "not a map"])
    server.report(odd)
    got = {name: values(family) for name, family in scrape(server).items()}
    assert got["gx2_link_reconnects"] == {}
    assert got["gx2_node_rate_hz"] == {(("node", "76"),): 50.0}
    assert got["gx2_node_rssi_dbm"] == {} and got["gx2_node_lqi"] == {}


def test_before_the_first_report_only_the_process_is_served(server) -> None:
    names = set(scrape(server))
    assert names and all(name.startswith("process_") for name in names), names


def test_a_port_in_use_is_refused_at_once() -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        with pytest.raises(OSError):
            MetricsServer(f"127.0.0.1:{taken.getsockname()[1]}")


@pytest.mark.parametrize(("text", "address"), [
    ("127.0.0.1:9105", ("127.0.0.1", 9105)), ("0.0.0.0:80", ("0.0.0.0", 80)),
    (":9105", ("127.0.0.1", 9105)), ("9105", ("127.0.0.1", 9105)),
    ("[::1]:9105", ("::1", 9105)), ("gateway.local:9105", ("gateway.local", 9105))])
def test_the_endpoint_is_host_and_port_on_the_loopback_unless_said(text: str,
                                                                   address: tuple) -> None:
    assert host_port(text) == address


@pytest.mark.parametrize("text", ["", "9105x", "host:0", "host:65536", "http://h:9105",
                                  "::1:9105", "[]:9105", "[127.0.0.1]:9105", " h:9105"])
def test_anything_else_is_refused_with_an_example(text: str) -> None:
    with pytest.raises(ValueError, match=r"HOST:PORT|brackets"):
        host_port(text)


def test_with_several_stations_each_links_series_carry_its_name(server) -> None:
    links = [{**report()["link"], "name": name, "state": state, "discarded": {"garbage": n}}
             for name, state, n in (("north", "down", 5), ("south", "up", 7))]
    server.report(report(stations=links))
    got = {name: {tuple(sorted(s.labels.items())): s.value for s in family.samples}
           for name, family in scrape(server).items()}
    assert got["gx2_link_up"] == {(("station", "north"),): 0.0, (("station", "south"),): 1.0}
    assert got["gx2_link_discarded_bytes"] == {
        (("reason", "garbage"), ("station", "north")): 5.0,
        (("reason", "garbage"), ("station", "south")): 7.0}
    # a gateway of one base station: its link's series as ever, without a label
    server.report(report(stations=links[:1]))
    got = {name: {tuple(sorted(s.labels.items())): s.value for s in family.samples}
           for name, family in scrape(server).items()}
    assert got["gx2_link_up"] == {(): 1.0}
