"""The status report: what ``gx2ctl status`` prints and the heartbeat publishes on
``gx2/gateway/status``, one map of the gateway, its link and every node."""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Protocol

from aspp.timing import BITS_PER_BYTE
from gateway.common.version import installed

from .health import station_reasons
from .outputs import OUTPUTS
from .owned import owned_reasons
from .station.replay import ReplayLink

if TYPE_CHECKING:
    from gateway.common.curve import AllowList

    from .config import GatewayConfig
    from .control import ControlServer
    from .health import Health
    from .outputs import Outputs
    from .outputs.zeromq import Publisher
    from .station.nodes import Node
    from .station.station import Station


class Reported(Protocol):
    """What a status report is made of (the gateway hands itself: app.py)."""

    config: GatewayConfig
    started: float
    health: Health
    outputs: Outputs
    publisher: Publisher
    control: ControlServer
    allow_list: AllowList | None
    stations: Sequence[Station]
    nodes: dict[int, Node]


def report(gateway: Reported) -> dict[str, Any]:
    now, monotonic = time.time(), time.monotonic()
    config = gateway.config
    health, published = gateway.health, gateway.outputs.published()
    stations = [station_link(station, monotonic) for station in gateway.stations]
    said = outputs_status(gateway.outputs)
    return {
        "gateway": {"version": installed(), "uptime": round(now - gateway.started, 3),
                    "time": now, "publish_endpoint": config.publish.endpoint,
                    "control_endpoint": config.control.endpoint,
                    "heartbeat_s": config.publish.heartbeat_s,
                    "published": gateway.publisher.sent,
                    "publish_failures": gateway.publisher.failed,
                    "control_requests": gateway.control.requests,
                    "control_rejected": gateway.control.rejected,
                    "control_dropped": gateway.control.dropped,
                    "control_late": gateway.control.late,
                    "curve_denied": gateway.allow_list.denied if gateway.allow_list else 0,
                    "publish_curve": bool(config.curve and config.curve.publish),
                    **health.gateway_status(monotonic)},  # (owned: folded in)
        # each station's link is in ``stations``; ``link`` is the interface's for a
        # client of one base station (the first, in a gateway of several)
        "link": one_station_link(stations[0]),
        "stations": stations,
        "nodes": [{**node.status(now), **health.status(node, monotonic),
                   "by_record": published.get(node.address, {})}
                  for node in gateway.nodes.values()],
        "replay": replay_status([s.link for s in gateway.stations]),
        "outputs": gateway.outputs.guard_status(),
        **said,
    }


def owned(gateway: Reported) -> list[str]:
    """Why what ``gateway`` owns delivers nothing now, from the maps status shows of
    them (its :class:`~.health.Health` folds it into its verdict, and logs each
    change)."""
    mqtt = gateway.outputs.get("mqtt")
    return owned_reasons([station_link(s, time.monotonic()) for s in gateway.stations],
                         {"mqtt": None if mqtt is None else mqtt.status()})


def outputs_status(outputs: Outputs) -> dict[str, dict[str, Any] | None]:
    """What each output of the table that says something of itself says, under its
    name (``recording``, ``live``, ...): None when it is not configured. A new output
    is here by its row alone."""
    said: dict[str, dict[str, Any] | None] = {}
    for name, row in OUTPUTS.items():
        if row.in_status:
            output = outputs.get(name)
            said[name] = output.status() if output is not None else None
    return said


def one_station_link(station: dict[str, Any]) -> dict[str, Any]:
    """A station's link as ``link`` shows it: without its name, its nodes, and what it
    heard (the station's, in ``stations``)."""
    return {key: value for key, value in station.items()
            if key not in ("name", "nodes", "heard", "heard_forgotten", "reasons")}


def station_link(station: Station, monotonic: float) -> dict[str, Any]:
    """One base station's serial link, as status shows it."""
    link, reader, scheduler = station.link, station.reader, station.scheduler
    assert link is not None
    stats = reader.decoder.stats
    return {"name": station.name, "port": station.config.port,
            "state": link.state, "since": link.since,
            "reconnects": link.reconnects, "bytes_read": link.bytes_read,
            "bytes_per_s": round(station.line.bytes_per_s(monotonic, link.bytes_read), 1),
            "line_bytes_per_s": station.config.baudrate / BITS_PER_BYTE,
            "over_capacity": station.line.over,
            "error": link.last_error,
            "discarded_bytes": stats.bytes_discarded,
            "discarded": {str(k): v for k, v in stats.discarded_bytes.items()},
            "unknown_node_packets": reader.unknown_node_packets,
            "bad_records": reader.bad_records,
            "retries": scheduler.stats.retries,
            "failures": scheduler.stats.failures,
            "unexpected_answers": scheduler.stats.unexpected,
            "nodes": station.configured,
            "heard": reader.heard.status(monotonic),
            "heard_forgotten": reader.heard.forgotten,
            "reasons": station_reasons(station.line, reader.heard, monotonic)}


def replay_status(links: list[Any]) -> dict[str, Any] | None:
    """What is being replayed (None when nothing is): the files, and how far."""
    replays = [link for link in links if isinstance(link, ReplayLink)]
    if not replays:
        return None
    return {"files": len(replays[0].replay.files), "reads": sum(r.reads for r in replays),
            "finished": all(r.finished for r in replays)}
