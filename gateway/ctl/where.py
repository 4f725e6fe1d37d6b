"""Where the gateway is: what a runner (tail, top, record) is handed by the parser,
below it, so that no runner imports the parser back."""

from __future__ import annotations

from dataclasses import dataclass

from gateway.common import curve


@dataclass(frozen=True)
class Endpoints:
    control: str
    publish: str | None
    """Known only from --config; otherwise asked of the gateway when needed."""
    keys: curve.ClientKeys | None = None
    publish_secured: bool | None = None
    """Whether the publish socket uses CURVE too (None: ask the gateway's status)."""
    heartbeat_s: float | None = None
    nodes: tuple[int, ...] | None = None
    """The configured nodes (None: ask the gateway's status)."""


@dataclass(frozen=True)
class Gateway:
    """One of the gateways gx2ctl was given, by the name it shows it under."""

    name: str
    where: Endpoints
    config: str | None = None
    """The configuration file it was named by, if any."""
