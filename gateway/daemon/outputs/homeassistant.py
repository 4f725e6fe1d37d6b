"""Home Assistant's MQTT discovery for the MQTT output (``mqtt.homeassistant: true``):
each node a device with four sensors (health, rate, samples lost over the radio, RSSI),
read by Home Assistant from the retained status the gateway already sends, so that
discovery adds no message a second.

Pure: the messages only; mqtt.py sends them (retained) when a node first appears, on
each connection, and whenever Home Assistant's status topic says ``online`` (it
restarted, and asks every device to announce itself again).
"""

from __future__ import annotations

import re
from typing import Any

from gateway.common.jsontext import compact_bytes

SENSORS: tuple[tuple[str, str, dict[str, str]], ...] = (
    ("health", "Health", {"icon": "mdi:heart-pulse"}),
    ("rate_hz", "Rate", {"unit_of_measurement": "Hz", "state_class": "measurement"}),
    ("lost_radio", "Lost over the radio", {"state_class": "total_increasing",
                                           "icon": "mdi:signal-off"}),
    ("rssi", "RSSI", {"unit_of_measurement": "dBm", "device_class": "signal_strength",
                      "state_class": "measurement"}),
)
"""Each sensor: its key in a node's status map, its name, its Home Assistant traits."""
UNSAFE = re.compile(r"[^A-Za-z0-9_-]")


def object_id(*parts: object) -> str:
    """An id discovery takes in a topic and as ``unique_id`` (letters, digits, _ and -)."""
    return UNSAFE.sub("_", "_".join(str(part) for part in ("gx2", *parts)))


def discovery(prefix: str, base: str, gateway: str, node: int,
              name: str | None) -> list[tuple[str, bytes]]:
    """The (topic, payload) of each of ``node``'s sensors, under Home Assistant's
    discovery ``prefix``, read from ``<base>/status``."""
    device = {"identifiers": [object_id(gateway, node)],
              "name": f"GX2 node {node}" + (f" ({name})" if name else ""),
              "manufacturer": "MicroStrain", "model": "3DM-GX2 / Inertia-Link"}
    messages = []
    for key, label, traits in SENSORS:
        unique = object_id(gateway, node, key)
        config: dict[str, Any] = {
            "name": label, "unique_id": unique,
            "state_topic": f"{base}/status",
            "value_template": "{% for n in value_json.nodes if n.node == " + str(node)
                              + " %}{{ n." + key + " }}{% endfor %}",
            "availability": [{"topic": f"{base}/availability"},
                             {"topic": f"{base}/{node}/availability"}],
            "availability_mode": "all", "device": device, **traits}
        messages.append((f"{prefix}/sensor/{unique}/config", compact_bytes(config)))
    return messages
