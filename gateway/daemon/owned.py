"""Why what the gateway owns delivers nothing, each an ERROR of the gateway's, folded
into its own verdict by :class:`~.health.Health` (the one verdict status shows and whose
changes are logged): from the status report's maps, each base station's link and the
MQTT output's broker.

Each is ERROR while it delivers nothing, as a node is: a base station whose link is
not up (its port does not exist, was unplugged, cannot be opened: every node behind
it is ERROR too), and an MQTT output that cannot reach its broker (every record for
the site's systems dropped). Issue 43: the gateway's line stayed OK through both, so
``gx2ctl status --check`` passed and ``gx2_gateway_health`` said 0."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any


def owned_reasons(stations: Sequence[Mapping[str, Any]],
                  outputs: Mapping[str, Mapping[str, Any] | None]) -> list[str]:
    """Why what the gateway owns delivers nothing (each an ERROR): from the status
    report's ``stations`` (each link's map) and its outputs' maps by name."""
    reasons = []
    for station in stations:
        if station.get("state") != "up":
            named = "base station" if len(stations) == 1 else \
                f"base station {station.get('name')}"
            error = station.get("error")  # (said the same while it is retried)
            reasons.append(f"{named} not up: {station.get('port')}: {error}" if error
                           else f"{named} {station.get('state')}")
    mqtt = outputs.get("mqtt")
    if mqtt and not mqtt.get("connected") and mqtt.get("error"):
        reasons.append(f"mqtt: {mqtt['error']}")
    return reasons

