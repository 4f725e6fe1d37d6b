"""The status report: what ``gx2ctl status`` prints and the heartbeat publishes on
``gx2/gateway/status``, one map of the gateway, its link and every node."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

from aspp.timing import BITS_PER_BYTE
from gateway.common.version import VERSION

from .replay import ReplayLink

if TYPE_CHECKING:
    from .app import Gateway


def report(gateway: Gateway) -> dict[str, Any]:
    now, monotonic = time.time(), time.monotonic()
    config = gateway.config
    link, reader, scheduler = gateway.link, gateway.reader, gateway.scheduler
    stats = reader.decoder.stats
    health, published = gateway.health, gateway.publisher.published()
    return {
        "gateway": {"version": VERSION, "uptime": round(now - gateway.started, 3),
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
                    **health.gateway_status(monotonic)},
        "link": {"port": config.base_station.port,
                 "state": "up" if link.up else "down", "since": link.since,
                 "reconnects": link.reconnects, "bytes_read": link.bytes_read,
                 "bytes_per_s": round(health.bytes_per_s(monotonic, link.bytes_read), 1),
                 "line_bytes_per_s": config.base_station.baudrate / BITS_PER_BYTE,
                 "over_capacity": health.line.over,
                 "error": link.last_error,
                 "discarded_bytes": stats.bytes_discarded,
                 "discarded": {str(k): v for k, v in stats.discarded_bytes.items()},
                 "unknown_node_packets": reader.unknown_node_packets,
                 "bad_records": reader.bad_records,
                 "retries": scheduler.stats.retries,
                 "failures": scheduler.stats.failures,
                 "unexpected_answers": scheduler.stats.unexpected},
        "nodes": [{**node.status(now), **health.status(node, monotonic),
                   "by_record": published.get(node.address, {})}
                  for node in gateway.nodes.values()],
        "recording": gateway.recorder.status() if gateway.recorder is not None else None,
        "replay": ({"files": len(link.replay.files), "reads": link.reads,
                    "finished": link.finished} if isinstance(link, ReplayLink) else None),
    }
