"""Reading what the simulator saw and did, under its lock, and what every published
payload must hold: the other side of the line, for the end-to-end tests."""

from __future__ import annotations

import time
from typing import Any

COMMON = {"node": int, "record": str, "command": int, "seq": int, "host_time": float,
          "lqi": int, "rssi": int}
"""Fields every published payload has; timed records add device_time (and time)."""


def received(sim, node: int, code: int) -> list:
    """The commands with ``code`` that the simulated node has received, in order."""
    return sim.call(lambda station, now: [c for c in station.nodes[node].log.commands
                                          if c.code == code])


def continuous(sim, node: int) -> int:
    """The record the simulated node streams (0: none)."""
    return sim.call(lambda station, now: station.nodes[node].continuous)


def station_stat(sim, name: str) -> Any:
    return sim.call(lambda station, now: getattr(station.stats, name))


def commands_to(sim, node: int) -> int:
    """Command packets the base station has taken from the host for ``node``."""
    return sim.call(lambda station, now: sum(
        1 for _, event in station.from_host_log
        if getattr(event, "node", None) == node and hasattr(event, "command")))


def check_payload(topic: str, payload: dict[str, Any], node: int, record: str,
                  command: int) -> None:
    assert topic == f"gx2/{node}/{record}"
    for field, kind in COMMON.items():
        assert isinstance(payload[field], kind), (field, payload)
    assert payload["node"] == node and payload["record"] == record
    assert payload["command"] == command
    assert payload["rssi"] < 0 and 0 <= payload["lqi"] <= 255
    assert abs(payload["host_time"] - time.time()) < 30
