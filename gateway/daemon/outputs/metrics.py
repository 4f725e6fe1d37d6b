"""The Prometheus endpoint (``metrics: {endpoint: HOST:PORT}``): ``GET /metrics``.

Nothing here touches the per-record path or the event loop. The loop hands over each
status report it makes (once a second at least, and whenever the link comes or goes);
prometheus-client's HTTP server, in a thread of its own, turns the latest one into
metrics when it is scraped. A report is built whole and never changed afterwards, so
handing it over is one reference assignment, with no lock, and a scrape reads one
consistent moment of the gateway. A scrape therefore costs the loop nothing. A loop
that stalls stops making reports: ``gx2_gateway_status_timestamp_seconds`` then stops
moving while the HTTP thread goes on answering, and an alert on its age catches it.

Which metric comes from which key of the report is the tables below: the names and
labels are part of the interface (docs/interface.md, section 8).
"""

from __future__ import annotations

import threading
from collections.abc import Iterator, Mapping
from typing import Any

from prometheus_client import CollectorRegistry, ProcessCollector, start_http_server
from prometheus_client.metrics_core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from gateway.common.endpoints import host_port
from gateway.common.reading import as_map, number

from ..health import Level
from ..station.heard import HEARD_MAX
from ..station.nodes import State
from . import Needs, Output

COUNTER, GAUGE = CounterMetricFamily, GaugeMetricFamily

GATEWAY = (
    ("gx2_messages_published_total", COUNTER, "Messages published (records and status)",
     "published"),
    ("gx2_publish_failures_total", COUNTER, "Messages ZeroMQ refused to publish",
     "publish_failures"),
    ("gx2_control_requests_total", COUNTER, "Control requests answered", "control_requests"),
    ("gx2_control_rejected_total", COUNTER, "Control requests refused as malformed",
     "control_rejected"),
    ("gx2_curve_denied_total", COUNTER, "Connections refused in the CURVE handshake",
     "curve_denied"),
)
LINK = (
    ("gx2_link_reconnects_total", COUNTER, "Times the base station's port was reopened",
     "reconnects"),
    ("gx2_link_bytes_read_total", COUNTER, "Bytes read from the base station", "bytes_read"),
    ("gx2_link_bytes_per_second", GAUGE, "Bytes read per second over the last 5 s",
     "bytes_per_s"),
    ("gx2_link_capacity_bytes_per_second", GAUGE, "What the serial line carries at most "
     "(baud rate / 10)", "line_bytes_per_s"),
    ("gx2_link_unknown_node_packets_total", COUNTER, "Packets from nodes not configured",
     "unknown_node_packets"),
    ("gx2_link_bad_records_total", COUNTER, "Packets whose record could not be decoded",
     "bad_records"),
    ("gx2_commands_retried_total", COUNTER, "Command packets sent again (NACK, no ACK, "
     "no reply)", "retries"),
    ("gx2_commands_failed_total", COUNTER, "Commands that failed after every retry",
     "failures"),
)
NODE = (
    ("gx2_node_received_total", COUNTER, "Records received from the node", "packets"),
    ("gx2_node_lost_radio_total", COUNTER, "Samples of its stream lost over the radio "
     "(from its timer's steps)", "lost_radio"),
    ("gx2_node_lost_station_down_total", COUNTER, "Samples of its stream missed while "
     "its base station was down (not the radio's)", "lost_station_down"),
    ("gx2_node_lost_gateway_total", COUNTER, "Its records the gateway could not publish",
     "lost_gateway"),
    ("gx2_node_reboots_total", COUNTER, "Its reboots (discovery packet or timer going "
     "back)", "reboots"),
    ("gx2_node_silences_total", COUNTER, "Times its stream fell silent", "silences"),
    ("gx2_node_rssi_dbm", GAUGE, "RSSI of its last record, dBm", "rssi"),
    ("gx2_node_lqi", GAUGE, "LQI of its last record", "lqi"),
    ("gx2_node_rate_hz", GAUGE, "Its records per second, over its last complete 2 s",
     "rate_hz"),
    ("gx2_node_expected_rate_hz", GAUGE, "The rate its stream runs at (absent while it "
     "streams nothing)", "expected_hz"),
    ("gx2_node_last_seen_timestamp_seconds", GAUGE, "UNIX time of its last record",
     "last_seen"),
)
RECORDING = (
    ("gx2_recording_written_total", COUNTER, "Messages written to recordings", "written"),
    ("gx2_recording_dropped_total", COUNTER, "Messages never written (queue full, disk "
     "failed, or a message that cannot be recorded)", "dropped"),
    ("gx2_recording_errors_total", COUNTER, "Disk failures while recording", "errors"),
    ("gx2_recording_bytes", GAUGE, "Bytes the recordings of its directory take (the file "
     "being written included)", "bytes"),
)
LSL = (
    ("gx2_lsl_pushed_total", COUNTER, "Samples pushed into Lab Streaming Layer outlets",
     "pushed"),
    ("gx2_lsl_dropped_total", COUNTER, "Samples never pushed (queue full, or liblsl "
     "refused them)", "dropped"),
)
MQTT = (
    ("gx2_mqtt_connects_total", COUNTER, "Connections made to the MQTT broker", "connects"),
    ("gx2_mqtt_sent_total", COUNTER, "Messages handed to the MQTT broker's connection",
     "sent"),
    ("gx2_mqtt_thinned_total", COUNTER, "Records not sent over MQTT by its rate_hz",
     "thinned"),
)
OUTPUT = (
    ("gx2_output_take_failures_total", COUNTER, "Messages an output failed to take (a "
     "bug, contained: the other outputs still got them; the log says what)",
     "take_failures"),
)
HEALTH_VALUES = {Level.OK: 0, Level.WARN: 1, Level.ERROR: 2}


def _table(rows: tuple[tuple[str, Any, str, str], ...], labels: list[str],
           entries: list[tuple[list[str], Mapping[str, Any]]]) -> Iterator[Metric]:
    """One family per row, one sample per (label values, map) where the map has it."""
    for name, kind, help_text, key in rows:
        family = kind(name, help_text, labels=labels)
        for values, source in entries:
            value = number(source.get(key))
            if value is not None:
                family.add_metric(values, value)
        yield family


def families(report: Mapping[str, Any]) -> Iterator[Metric]:
    """The metrics of one status report (the map ``gx2ctl --json status`` prints)."""
    gateway, link = as_map(report.get("gateway")), as_map(report.get("link"))
    info = GAUGE("gx2_gateway_info", "The gateway's version", labels=["version"])
    info.add_metric([str(gateway.get("version"))], 1)
    yield info
    made, uptime = number(gateway.get("time")), number(gateway.get("uptime"))
    if made is not None:
        yield GAUGE("gx2_gateway_status_timestamp_seconds", "UNIX time the status served "
                    "was made (once a second: older means the gateway's loop is stuck)",
                    value=made)
        if uptime is not None:
            yield GAUGE("gx2_gateway_start_time_seconds", "UNIX time the gateway started",
                        value=made - uptime)
    yield from _table(GATEWAY, [], [([], gateway)])
    if gateway.get("health") in HEALTH_VALUES:
        yield GAUGE("gx2_gateway_health", "The gateway's health, the worst of what it "
                    "owns: 0 OK, 1 WARN (its recorder's queue overflowed, a line over "
                    "capacity, an output failed to take messages, a node not configured "
                    "streams), 2 ERROR (a base station's link not up, the MQTT broker "
                    "unreachable, its recorder cannot write); status gives the reasons",
                    value=HEALTH_VALUES[gateway["health"]])
    # a gateway of one base station: its link's series without labels, as ever; of
    # several, each station's series labelled with its name
    stations = [s for s in report.get("stations") or () if isinstance(s, Mapping)]
    if len(stations) > 1:
        labels, links = ["station"], [([str(s.get("name"))], s) for s in stations]
    else:
        labels, links = [], [([], link)]
    up = GAUGE("gx2_link_up", "1 while the base station's port is open", labels=labels)
    for values, source in links:
        up.add_metric(values, float(source.get("state") == "up"))
    yield up
    yield from _table(LINK, labels, links)
    discarded = COUNTER("gx2_link_discarded_bytes_total", "Bytes the decoder discarded, "
                        "by reason", labels=[*labels, "reason"])
    for values, source in links:
        for reason, count in as_map(source.get("discarded")).items():
            if (value := number(count)) is not None:
                discarded.add_metric([*values, str(reason)], value)
    yield discarded
    yield from _heard(stations)

    nodes = [n for n in report.get("nodes") or () if isinstance(n, Mapping)
             and number(n.get("node")) is not None]
    entries = [([str(n["node"])], n) for n in nodes]
    yield from _table(NODE, ["node"], entries)
    names = GAUGE("gx2_node_info", "A node's name and its base station's",
                  labels=["node", "name", "station"])
    states = GAUGE("gx2_node_state", "1 for the state the node is in, 0 for the others",
                   labels=["node", "state"])
    health = GAUGE("gx2_node_health", "0 OK, 1 WARN, 2 ERROR (status gives the reasons)",
                   labels=["node"])
    drift = GAUGE("gx2_node_clock_drift_ppm", "How fast its crystal runs against the "
                  "host's clock (positive: fast)", labels=["node"])
    locked = GAUGE("gx2_node_clock_locked", "1 once its clock estimate has locked",
                   labels=["node"])
    floor_age = GAUGE("gx2_node_clock_floor_age_seconds", "Device seconds since a packet "
                      "came near its clock's floor (while locked)", labels=["node"])
    published = COUNTER("gx2_records_published_total", "Records published, by node and record",
                        labels=["node", "record"])
    for (node,), entry in entries:
        names.add_metric([node, str(entry.get("name") or ""), str(entry.get("station") or "")],
                         1)
        for state in State:
            states.add_metric([node, str(state)], float(entry.get("state") == state))
        if entry.get("health") in HEALTH_VALUES:
            health.add_metric([node], HEALTH_VALUES[entry["health"]])
        clock = entry.get("clock")
        if isinstance(clock, Mapping):
            if (value := number(clock.get("drift_ppm"))) is not None:
                drift.add_metric([node], value)
            locked.add_metric([node], float(clock.get("locked") is True))
            if (value := number(clock.get("floor_age_s"))) is not None:
                floor_age.add_metric([node], value)
        for record, count in as_map(entry.get("by_record")).items():
            if (value := number(count)) is not None:
                published.add_metric([node, str(record)], value)
    yield from (names, states, health, drift, locked, floor_age, published)

    recording = report.get("recording")
    if isinstance(recording, Mapping):
        yield from _table(RECORDING, [], [([], recording)])
        # (the gateway's health is the worst of all it owns: this is the recorder's)
        yield GAUGE("gx2_recording_failing", "1 while the recorder cannot write "
                    "(recording.failure says why)", value=float(bool(recording.get("failure"))))
    lsl = report.get("lsl")
    if isinstance(lsl, Mapping):
        yield from _table(LSL, [], [([], lsl)])
    mqtt = report.get("mqtt")
    if isinstance(mqtt, Mapping):
        yield GAUGE("gx2_mqtt_connected", "1 while the MQTT output is connected to its "
                    "broker", value=float(mqtt.get("connected") is True))
        yield from _table(MQTT, [], [([], mqtt)])
        dropped = COUNTER("gx2_mqtt_dropped_total", "Messages the MQTT output dropped: "
                          "its queue full, or the broker away", labels=["reason"])
        for reason, count in as_map(mqtt.get("dropped")).items():
            if (value := number(count)) is not None:
                dropped.add_metric([str(reason)], value)
        yield dropped
    yield from _table(OUTPUT, ["output"], [([str(name)], as_map(said)) for name, said
                                           in as_map(report.get("outputs")).items()])


def _heard(stations: list[Mapping[str, Any]]) -> Iterator[Metric]:
    """Each base station's unconfigured nodes heard (its ``heard``), labelled with its
    name whatever the number of stations (a new family: no unlabelled series to keep)."""
    heard = GAUGE("gx2_station_heard_nodes", "Addresses the base station heard that are "
                  f"not configured (at most {HEARD_MAX} remembered)", labels=["station"])
    streaming = GAUGE("gx2_station_heard_streaming_nodes", "Of those, the ones streaming "
                      "on its channel now (they take radio time from the configured ones)",
                      labels=["station"])
    for station in stations:
        nodes = station.get("heard")
        if isinstance(nodes, list):
            name = [str(station.get("name"))]
            heard.add_metric(name, len(nodes))
            streaming.add_metric(name, sum(1 for node in nodes if isinstance(node, Mapping)
                                           and number(node.get("rate_hz")) is not None))
    yield from (heard, streaming)


class StatusCollector(Collector):
    """The metrics of the latest status report it was given."""

    def __init__(self) -> None:
        self.report: Mapping[str, Any] | None = None

    def collect(self) -> Iterator[Metric]:
        report = self.report  # (one read: the loop replaces it whole, never changes it)
        if report is not None:
            yield from families(report)


class MetricsServer(Output):
    """``GET /metrics`` on HOST:PORT, served by prometheus-client in a thread."""

    takes_messages = False

    def __init__(self, endpoint: str) -> None:
        host, port = host_port(endpoint)
        self.endpoint = endpoint
        self.collector = StatusCollector()
        registry = CollectorRegistry()
        registry.register(self.collector)
        ProcessCollector(registry=registry)  # the gateway's CPU, memory, open files
        # raises OSError (in use, no such address) before anything runs
        self._server, self._thread = start_http_server(port, host, registry)

    def report(self, status: Mapping[str, Any]) -> None:
        """Serve ``status`` from now on (called on the loop)."""
        self.collector.report = status

    def close(self, seconds: float = 1.0) -> None:
        """Stop serving within ``seconds``: the server's shutdown waits up to its poll
        interval (0.5 s), so it runs in a daemon thread waited for that long at most
        (left to the process's exit past it, as the server's thread is)."""
        def stop() -> None:
            self._server.shutdown()
            self._server.server_close()
        stopping = threading.Thread(target=stop, name="gx2-metrics-stop", daemon=True)
        stopping.start()
        stopping.join(seconds)
        if not stopping.is_alive():
            self._thread.join(max(0.0, seconds))


def make(needs: Needs) -> MetricsServer:
    assert needs.config.metrics is not None
    return MetricsServer(needs.config.metrics.endpoint)

