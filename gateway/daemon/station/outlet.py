"""What a station hands out, and nothing more: its ways to the gateway's outputs.

A station publishes records and replays recorded messages through an :class:`Outlet`,
and shows its serial bytes to a :class:`SerialTap` (the recorder, when recording). It
is given both and never imports what stands behind them (:mod:`gateway.daemon.outputs`):
a record's way out of a station is one-way, and no output can call back into it.
"""

from __future__ import annotations

from typing import Any, Protocol


class Publishes(Protocol):
    def publish(self, node: int, record: str, payload: dict[str, Any]) -> bool:
        """One record of ``node``; False if it could not be published (counted)."""
        ...


class Outlet(Publishes, Protocol):
    def replayed(self, name: str, payload: dict[str, Any]) -> bool:
        """A message of a recording, published again on its recorded topic."""
        ...


class SerialTap(Protocol):
    def serial(self, data: bytes, host_time: float, monotonic: float,
               channel: str) -> None:
        """A read from the port (never blocks: the recorder queues it)."""
        ...

    def sent(self, data: bytes, host_time: float, monotonic: float, channel: str) -> None:
        """A write to the port."""
        ...
