"""The gateway's configuration: ``gx2-gateway --config nodes.yaml``.

The keys of CONTRACT section 3, plus a few documented in README (marked "added" below).
Strict: an unknown key is an error, so a typo never passes silently.
"""

from __future__ import annotations

import ipaddress
from pathlib import Path
from typing import Annotated

import serial
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, field_validator, model_validator

from aspp.frame import MAX_NODE, MIN_NODE
from aspp.records import checked

from . import curve
from .cli_args import check_endpoint
from .sim.config import from_url
from .yamlconfig import ConfigError, load_model

__all__ = ["ConfigError", "GatewayConfig", "load_config"]


class _Strict(BaseModel):
    # strict: a YAML "yes" or 1 is not a bool, "115200" not an int (ints pass as floats)
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)


Endpoint = Annotated[str, AfterValidator(check_endpoint)]


def _openable_port(value: str) -> str:
    """A device path, a pyserial URL whose scheme pyserial knows, or sim://."""
    if value.startswith("sim://") or "://" not in value:
        return value
    try:
        serial.serial_for_url(value, do_not_open=True)
    except (ValueError, serial.SerialException) as error:
        raise ValueError(f"{value!r} is not a device path, sim:// or a pyserial URL: "
                         f"{error}") from None
    return value


class BaseStationConfig(_Strict):
    port: Annotated[str, Field(min_length=1), AfterValidator(_openable_port)]
    """A device path, a pyserial URL, or sim:// (the built-in simulator)."""
    baudrate: Annotated[int, Field(ge=1200, le=4_000_000)] = 115200
    idle_ms: Annotated[float, Field(ge=1, le=1000)] = 30.0
    """Added: a line silent this long has finished what it was sending."""


class PublishConfig(_Strict):
    endpoint: Endpoint = "tcp://127.0.0.1:5555"
    heartbeat_s: Annotated[float, Field(gt=0, le=60)] = 1.0
    """Added: period of the gx2/gateway/status message."""
    high_water_mark: Annotated[int, Field(ge=100, le=10_000_000)] = 20_000
    """Added: messages queued per subscriber before the slowest one loses some."""


class ControlConfig(_Strict):
    endpoint: Endpoint = "tcp://127.0.0.1:5556"
    allow_eeprom_write: bool = False
    allow_any_eeprom_address: bool = False
    """Added: write EEPROM words other than the ones the reference documents (0xFCA2
    data rate divider, 0xFCA6 auto-start); a wrong word can break a node's calibration."""


class CurveConfig(_Strict):
    """Added: CURVE encryption and authentication (keys from ``gx2ctl keygen``)."""

    server_key: Annotated[str, Field(min_length=1)]
    """The gateway's ``.key_secret`` file (not readable by every user)."""
    clients: Annotated[list[str], Field(min_length=1)]
    """The client public keys let in: 40-character Z85 keys or ``.key`` files."""
    publish: bool = True
    """Encrypt the publish socket too (subscribers then need an allowed key); false
    leaves the data stream open to anyone who can reach it."""

    @field_validator("server_key")
    @classmethod
    def _server_pair(cls, value: str) -> str:
        curve.load_key_pair(value)  # (a CurveError is a ValueError: a config error)
        return value

    @field_validator("clients")
    @classmethod
    def _client_keys(cls, values: list[str]) -> list[str]:
        for index, value in enumerate(values):
            try:
                curve.public_key(value)
            except curve.CurveError as error:
                raise ValueError(f"[{index}]: {error}") from None
        return values

    def server_pair(self) -> curve.KeyPair:
        return curve.load_key_pair(self.server_key)

    def allowed(self) -> frozenset[bytes]:
        return frozenset(curve.public_key(value) for value in self.clients)


def is_loopback_endpoint(endpoint: str) -> bool:
    """ipc://, inproc://, or tcp:// on a loopback address: unreachable from elsewhere."""
    scheme, _, rest = endpoint.partition("://")
    if scheme != "tcp":
        return True
    host = rest.rpartition(":")[0].strip("[]")
    if host in ("localhost", "lo"):
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # *, a host name or an interface name: possibly reachable


class ShutdownConfig(_Strict):
    """Added: what the gateway does on SIGTERM/SIGINT (it exits within 2 s either way)."""

    stop_streams: bool = False
    """Send 0xFA to the streams it started, best effort, within the exit budget. Off by
    default: a restarted gateway re-arms them, so leaving them on loses no data."""


class NodeConfig(_Strict):
    address: Annotated[int, Field(ge=MIN_NODE, le=MAX_NODE, strict=True)]
    name: Annotated[str, Field(min_length=1, max_length=64)] | None = None
    stream: str | None = None

    @field_validator("stream")
    @classmethod
    def _streamable(cls, value: str | None) -> str | None:
        return None if value is None else checked(value, streamable=True).name

    @property
    def label(self) -> str:
        return f"{self.address} ({self.name})" if self.name else str(self.address)


class GatewayConfig(_Strict):
    base_station: BaseStationConfig
    publish: PublishConfig = PublishConfig()
    control: ControlConfig = ControlConfig()
    shutdown: ShutdownConfig = ShutdownConfig()
    curve: CurveConfig | None = None
    nodes: Annotated[list[NodeConfig], Field(min_length=1)]

    @model_validator(mode="after")
    def _distinct(self) -> GatewayConfig:
        seen: set[int] = set()
        for index, node in enumerate(self.nodes):
            if node.address in seen:
                raise ValueError(f"nodes[{index}].address: {node.address} is already "
                                 "configured")
            seen.add(node.address)
        if self.publish.endpoint == self.control.endpoint:
            raise ValueError("publish.endpoint and control.endpoint must differ")
        if self.curve is None and not is_loopback_endpoint(self.control.endpoint):
            raise ValueError(f"control.endpoint: {self.control.endpoint} may be reachable "
                             "from other hosts, and control can write EEPROM and stop "
                             "streams: bind it to 127.0.0.1 or an ipc:// path, or "
                             "configure curve (see README)")
        if self.base_station.port.startswith("sim://"):
            try:
                from_url(self.base_station.port, [n.address for n in self.nodes])
            except ValueError as error:
                raise ValueError(f"base_station.port: {error}") from None
        return self


def load_config(path: str | Path) -> GatewayConfig:
    """Read and validate a gateway configuration; raises ConfigError (one line)."""
    return load_model(path, GatewayConfig)
