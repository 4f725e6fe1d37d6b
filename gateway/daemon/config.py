"""The gateway's configuration: ``gx2-gateway --config nodes.yaml``.

The keys of the interface (docs/interface.md, section 3), plus a few marked "added" below.
Strict: an unknown key is an error, so a typo never passes silently.
"""

from __future__ import annotations

import ipaddress
import math
import os
import re
import socket
from pathlib import Path
from typing import Annotated, Any
from urllib.parse import urlsplit, urlunsplit

from pydantic import (
    AfterValidator,
    Field,
    PrivateAttr,
    ValidationInfo,
    field_validator,
    model_validator,
)

from aspp.frame import MAX_NODE, MIN_NODE
from aspp.records import checked
from aspp.temperature import DEFAULT_GYRO, gyro_model
from gateway.common import curve
from gateway.common.endpoints import (
    DEFAULT_CONTROL,
    DEFAULT_LIVE,
    DEFAULT_METRICS,
    DEFAULT_PUBLISH,
    check_endpoint,
    check_host_port,
    host_port,
    is_loopback,
)
from gateway.common.strict import Strict, load_model
from gateway.common.topics import STATION_NAME, default_station_name
from gateway.common.yamlfile import ConfigError

from . import tls
from .station import ports

__all__ = ["ConfigError", "GatewayConfig", "load_config"]

Endpoint = Annotated[str, AfterValidator(check_endpoint)]


class BaseStationConfig(Strict):
    port: Annotated[str, Field(min_length=1)]
    """A device path, a pyserial URL, or sim:// (the built-in simulator)."""
    baudrate: Annotated[int, Field(ge=1200, le=4_000_000)] = 115200
    idle_ms: Annotated[float, Field(ge=1, le=1000)] = 30.0
    """Added: a line silent this long has finished what it was sending."""
    latency_ms: Annotated[float, Field(ge=0, le=1000)] = 3.0
    """Added: milliseconds from a sample to its packet leaving the base station when
    nothing waits: the radio's part of a packet's delay, which the host cannot see.
    3 ms: a 0xC2 reply is about 57 bytes on the air with 802.15.4's framing, 1.8 ms at
    250 kbit/s, plus the node's and the base station's handling (docs/gateway.md,
    "Sample time", says how to measure it)."""


class PublishConfig(Strict):
    endpoint: Endpoint = DEFAULT_PUBLISH
    heartbeat_s: Annotated[float, Field(gt=0, le=60)] = 1.0
    """Added: period of the gx2/gateway/status message."""
    high_water_mark: Annotated[int, Field(ge=100, le=10_000_000)] = 20_000
    """Added: messages queued per subscriber before the slowest one loses some."""


class ControlConfig(Strict):
    endpoint: Endpoint = DEFAULT_CONTROL
    allow_eeprom_write: bool = False
    allow_any_eeprom_address: bool = False
    """Added: write EEPROM words other than the ones the reference documents (0xFCA2
    data rate divider, 0xFCA6 auto-start); a wrong word can break a node's calibration."""


class CurveConfig(Strict):
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


class ShutdownConfig(Strict):
    """Added: what the gateway does on SIGTERM/SIGINT (it exits within 2 s either way)."""

    stop_streams: bool = False
    """Send 0xFA to the streams it started, best effort, within the exit budget. Off by
    default: a restarted gateway re-arms them, so leaving them on loses no data."""


STATE_DIRECTORY = "/var/lib/gx2-gateway"
"""The state directory of deploy/gx2-gateway.service (``StateDirectory=gx2-gateway``):
made by systemd, owned by the service's user, writable under ``ProtectSystem=strict``."""


def default_record_directory() -> str:
    """``$STATE_DIRECTORY/recordings``, else ``STATE_DIRECTORY/recordings``: so
    ``record: {}`` records where the unit lets the gateway write, wherever it puts it.

    systemd.exec(5), "StateDirectory=": the variable holds the full paths of the unit's
    state directories, joined by ":" when there are several; the first is taken."""
    state = os.environ.get("STATE_DIRECTORY", "").split(":")[0]
    return str(Path(state or STATE_DIRECTORY) / "recordings")


class RecordConfig(Strict):
    """Recording to MCAP files (docs/recording.md)."""

    directory: Annotated[str, Field(min_length=1, default_factory=default_record_directory)]
    """Created if missing. Added: a default, the unit's state directory's
    ``recordings`` (``default_record_directory``)."""
    rotate_minutes: Annotated[float, Field(gt=0, le=7 * 24 * 60)] = 60.0
    """A new file at least this often."""
    rotate_mb: Annotated[float, Field(gt=0, le=1_000_000)] = 256.0
    """Or when a file reaches this size (MB of 10^6 bytes)."""
    queue: Annotated[int, Field(ge=100, le=10_000_000)] = 100_000
    """Added: messages waiting for the disk before new ones are dropped (and counted):
    near three minutes of a saturated link (about 600 reads and records a second), and
    53 MB of memory when full (tracemalloc, half reads, half 0xC2 records)."""
    keep_gb: Annotated[float, Field(gt=0)] | None = None
    """Added: finished files are deleted, oldest first, to keep the directory's
    recordings within this many GB (10^9 bytes); never the file being written. None:
    no limit."""
    keep_days: Annotated[float, Field(gt=0)] | None = None
    """Added: finished files older than this many days are deleted, oldest first; never
    the file being written. None: kept however old."""


class MetricsConfig(Strict):
    """Prometheus metrics (docs/interface.md, section 8)."""

    endpoint: Annotated[str, AfterValidator(check_host_port)] = DEFAULT_METRICS
    """HOST:PORT of the HTTP endpoint serving GET /metrics (a bare :PORT or PORT is on
    127.0.0.1; [::1]:PORT for IPv6). Read-only: any address a scraper reaches will do."""


class TlsPair(Strict):
    """A certificate and its key, both given or neither, each file read and checked as
    the configuration is (the live view's server pair, an MQTT client's)."""

    tls_cert: Annotated[str, Field(min_length=1)] | None = None
    """A PEM certificate (with tls_key)."""
    tls_key: Annotated[str, Field(min_length=1)] | None = None
    """The PEM private key of tls_cert (PKCS#8, PKCS#1 or SEC1), not encrypted."""

    @model_validator(mode="before")
    @classmethod
    def _both_or_neither(cls, data: Any) -> Any:
        # said before either file is read: the other one is the mistake
        if isinstance(data, dict) and ((data.get("tls_cert") is None)
                                       != (data.get("tls_key") is None)):
            raise ValueError("tls_cert and tls_key: give both, or neither")
        return data

    @field_validator("tls_cert")
    @classmethod
    def _cert(cls, path: str | None) -> str | None:
        return tls.check_cert(path)

    @field_validator("tls_key")
    @classmethod
    def _key(cls, path: str | None, info: ValidationInfo) -> str | None:
        return tls.check_key(path, info.data.get("tls_cert"))


class LiveConfig(TlsPair):
    """Added: the live view, a Foxglove WebSocket server (docs/live.md); with
    tls_cert and tls_key it takes wss:// only."""

    endpoint: Annotated[str, AfterValidator(check_host_port)] = DEFAULT_LIVE
    """HOST:PORT it listens on (as metrics.endpoint). Read-only, and unauthenticated:
    another host than the loopback is allowed, and logged once."""
    backlog: Annotated[int, Field(ge=16, le=1_000_000)] = 1024
    """Messages queued for each viewer; a viewer that reads slower loses the oldest."""


LSL_NAME = r"[A-Za-z0-9][A-Za-z0-9_.-]{0,31}"
"""What an LSL stream name's prefix may be: a word LabRecorder shows and a file name
may hold."""


class LslConfig(Strict):
    """Added: a Lab Streaming Layer outlet per node and record (docs/labrecorder.md);
    the optional extra ``[lsl]`` (pylsl)."""

    prefix: str = "gx2"
    """Streams are named ``<prefix>-<node>-<record>``."""
    queue: Annotated[int, Field(ge=100, le=10_000_000)] = 10_000
    """Samples waiting for liblsl before new ones are dropped (and counted): some
    seconds of a saturated line."""

    @field_validator("prefix")
    @classmethod
    def _stream_name(cls, value: str) -> str:
        if not re.fullmatch(LSL_NAME, value):
            raise ValueError(f"{value!r}: 1 to 32 letters, digits, '_', '.' or '-', "
                             "starting with a letter or digit")
        return value


MQTT_SCHEMES = {"mqtt": 1883, "mqtts": 8883}
"""The schemes of ``mqtt.url`` and each one's default port (mqtts: TLS)."""
MQTT_LEVEL = r"^[^/+#\x00]+$"
"""One level of an MQTT topic: no separator, no wildcard."""


def shown_url(url: str) -> str:
    """``url`` as a message may show it: a user and password in it left out
    (``mqtt://***@broker:1883``). No credential is ever written to a log line, an
    error, a status field or a metric label."""
    parts = urlsplit(url)
    if "@" not in parts.netloc:
        return url
    return urlunsplit(parts._replace(netloc="***@" + parts.netloc.rpartition("@")[2]))


def check_host(host: str) -> str | None:
    """Why the resolver would refuse ``host`` (a name or an IP address; "has ...", "is
    ..."), as
    ``getaddrinfo`` encodes it (IDNA: labels of 1 to 63 characters, 253 in all), or
    None. A name it refuses raises in the connection's thread, not as a failure to
    connect (paho's thread died of it, unseen)."""
    try:
        ipaddress.ip_address(host)
        return None
    except ValueError:
        pass
    labels = host.removesuffix(".").split(".")
    if any(not label for label in labels):
        return "has an empty label (two dots in a row, or a dot first)"
    if any(len(label) > 63 for label in labels):
        return "has a label longer than 63 characters"
    try:
        encoded = host.encode("idna")
    except UnicodeError as error:
        return f"is not a name the resolver takes ({error})"
    if len(encoded.removesuffix(b".")) > 253:
        return "is longer than 253 characters"
    return None


def check_mqtt_url(url: str) -> str:
    """``mqtt://HOST[:PORT]`` or ``mqtts://HOST[:PORT]``, its scheme in lower case
    (schemes are case-insensitive: ``MQTTS://`` is TLS too), its host one the resolver
    takes; ValueError (one line, never the url's user or password) if not."""
    parts, shown = urlsplit(url), shown_url(url)
    if parts.scheme not in MQTT_SCHEMES:
        raise ValueError(f"{shown!r}: the scheme is {parts.scheme or 'missing'!r}; "
                         "give mqtt://HOST:PORT or mqtts://HOST:PORT")
    try:
        port = parts.port
    except ValueError:
        raise ValueError(f"{shown!r}: the port is not a number in 1..65535") from None
    if not parts.hostname or port == 0 or parts.path not in ("", "/") or "?" in url \
            or "#" in url or parts.username is not None:
        raise ValueError(f"{shown!r}: give mqtt://HOST:PORT (no path, query, fragment or "
                         "user: the user and password are mqtt.username and "
                         "mqtt.password)")
    problem = check_host(parts.hostname)
    if problem:
        raise ValueError(f"{shown!r}: the host {parts.hostname!r} {problem}")
    return parts.scheme + url[len(parts.scheme):]


def check_prefix(prefix: str) -> str:
    """Topic levels joined by ``/``, none empty, no wildcard."""
    if not all(re.match(MQTT_LEVEL, level) for level in prefix.split("/")):
        raise ValueError(f"{prefix!r}: topic levels joined by '/', none empty, without "
                         "'+' or '#'")
    return prefix


class MqttConfig(TlsPair):
    """The MQTT output (docs/site.md): records as JSON, the status and availability,
    to a broker the site runs; tls_cert and tls_key: a client certificate, for a broker
    that asks for one."""

    url: Annotated[str, AfterValidator(check_mqtt_url)]
    """``mqtt://HOST:PORT`` (1883 if no port) or ``mqtts://HOST:PORT`` (TLS, 8883)."""
    prefix: Annotated[str, AfterValidator(check_prefix)] = "gx2"
    name: Annotated[str, Field(pattern=MQTT_LEVEL, max_length=64,
                               default_factory=socket.gethostname)]
    """The gateway's topic level (``<prefix>/<name>/...``): the host's name if not given."""
    username: Annotated[str, Field(min_length=1)] | None = None
    password: str | None = None
    tls_ca: Annotated[str, Field(min_length=1)] | None = None
    """PEM certificates the broker's is checked against (mqtts://); the system's if not
    given."""
    rate_hz: float | dict[str, float] | None = None
    """Records sent at most this often, per node and record: a number for every record,
    or a map record name -> Hz (records not named go at their full rate). None: every
    sample."""
    queue: Annotated[int, Field(ge=100, le=1_000_000)] = 10_000
    """Messages waiting for the broker before new ones are dropped (and counted)."""
    client_id: Annotated[str, Field(min_length=1, max_length=128)] | None = None
    """The MQTT client id: ``gx2-gateway-<name>`` if not given."""
    homeassistant: bool = False
    """Announce each node's health, rate, radio losses and RSSI to Home Assistant's MQTT
    discovery (again whenever Home Assistant says it is online)."""
    homeassistant_prefix: Annotated[str, AfterValidator(check_prefix)] = "homeassistant"
    """Home Assistant's discovery prefix (its MQTT integration's setting)."""

    @model_validator(mode="before")
    @classmethod
    def _pairs(cls, data: Any) -> Any:
        if isinstance(data, dict):
            if data.get("password") is not None and data.get("username") is None:
                raise ValueError("password: given without username")
            url = data.get("url")
            if (isinstance(url, str) and urlsplit(url).scheme == "mqtt" and any(
                    data.get(key) is not None for key in ("tls_ca", "tls_cert"))):
                raise ValueError("tls_ca and tls_cert need an mqtts:// url")
        return data

    @field_validator("tls_ca")
    @classmethod
    def _ca(cls, path: str | None) -> str | None:
        return tls.check_cert(path)

    @field_validator("rate_hz", mode="before")
    @classmethod
    def _records(cls, value: Any) -> Any:
        """Each rate a finite number of Hz above 0 (``.inf`` would be every sample, as
        leaving it out is), each record a known one: said in one line."""
        for record, rate in value.items() if isinstance(value, dict) else [(None, value)]:
            if record is not None:
                checked(record)
            if rate is not None and (isinstance(rate, bool) or not isinstance(
                    rate, int | float) or not 0 < rate < math.inf):
                where = f"{record}: " if record is not None else ""
                raise ValueError(f"{where}{rate!r}: a number of Hz above 0 (leave it out "
                                 "to send every sample)")
        return value

    def cleartext(self) -> str | None:
        """The warning for a user and password sent in the clear (plain ``mqtt://`` to
        a host that is not this machine: anyone on the way reads them), or None. Said
        at start and by ``--check``, as the live view says a reachable endpoint."""
        if self.username is None or urlsplit(self.url).scheme != "mqtt":
            return None
        host = urlsplit(self.url).hostname or ""
        if host == "localhost" or is_loopback(f"tcp://{host}:0"):
            return None
        return (f"mqtt.password: mqtt.username and its password go to {host} "
                "unencrypted (mqtt:// to another host): anyone on the way can read "
                "them; use mqtts:// (TLS)")

    def every_s(self, record: str) -> float | None:
        """Least seconds of sample time between two records sent (None: every one)."""
        rate = self.rate_hz.get(record) if isinstance(self.rate_hz, dict) else self.rate_hz
        return None if rate is None else 1.0 / rate


FLOOR_UNSEEN_S = 30.0
"""The default of health.floor_unseen_s: from 30 s unseen, ``time`` may be late by 1 ms
(aspp.clock.DRIFT_ERROR), the worst error the sample time's targets allow
(docs/performance-history.md)."""


class HealthConfig(Strict):
    """Added: when a node is OK, WARN or ERROR (docs/interface.md, section 8)."""

    window_s: Annotated[float, Field(ge=2, le=3600)] = 60.0
    """The recent past that losses and RSSI are judged over: the last minute."""
    rate_under_percent: Annotated[float, Field(gt=0, le=100)] = 5.0
    """WARN when a stream's rate is more than this far under its expected rate."""
    radio_loss_percent: Annotated[float, Field(ge=0, le=100)] = 5.0
    """WARN when more than this share of a node's samples was lost over the radio in
    the window."""
    weak_rssi_dbm: Annotated[int, Field(ge=-128, le=0)] = -90
    """WARN when the median RSSI over the window is under this."""
    settle_s: Annotated[float, Field(ge=2, le=600)] = 10.0
    """A stream (re)started this recently is not judged by its rate or its clock yet,
    nor anything by a window this short: each needs some seconds of records."""
    floor_unseen_s: Annotated[float, Field(ge=2, le=600)] = FLOOR_UNSEEN_S
    """WARN when no packet of a node came near its clock's floor for this long (device
    seconds): ``time`` may be late meanwhile by the bound status gives (`late_ms`)."""


class NodeEntry(Strict):
    address: Annotated[int, Field(ge=MIN_NODE, le=MAX_NODE, strict=True)]
    name: Annotated[str, Field(min_length=1, max_length=64)] | None = None
    stream: str | int | None = None
    """The record it streams from start-up: a name, "0xNN", or the byte (YAML reads
    ``0xCE`` as the number 206)."""
    gyro: str = DEFAULT_GYRO
    """Added: its rate sensor model, which sets how its gyro temperatures convert."""

    @field_validator("stream")
    @classmethod
    def _streamable(cls, value: str | int | None) -> str | None:
        return None if value is None else checked(value, streamable=True).name

    @field_validator("gyro")
    @classmethod
    def _known_gyro(cls, value: str) -> str:
        gyro_model(value)
        return value

    @property
    def label(self) -> str:
        return f"{self.address} ({self.name})" if self.name else str(self.address)


class StationConfig(BaseStationConfig):
    """Added: one of several base stations (``base_stations:``), with its own nodes."""

    name: Annotated[str, Field(pattern=STATION_NAME)] | None = None
    """How status, top, metrics and recordings name it; station1, station2... if not
    given (by its place in the list)."""
    nodes: list[NodeEntry]


class GatewayConfig(Strict):
    base_station: BaseStationConfig | None = None
    base_stations: Annotated[list[StationConfig], Field(min_length=1)] | None = None
    """Added: several base stations, each with its own nodes, instead of
    ``base_station:`` and ``nodes:`` (which are a list of one)."""
    publish: PublishConfig = PublishConfig()
    control: ControlConfig = ControlConfig()
    shutdown: ShutdownConfig = ShutdownConfig()
    curve: CurveConfig | None = None
    record: RecordConfig | None = None
    metrics: MetricsConfig | None = None
    live: LiveConfig | None = None
    lsl: LslConfig | None = None
    mqtt: MqttConfig | None = None
    """Added: the MQTT output (section 9 of the interface)."""
    health: HealthConfig = HealthConfig()
    nodes: list[NodeEntry] | None = None
    """The one station's nodes (with ``base_station:``); :attr:`all_nodes` is every
    node of every station."""

    @model_validator(mode="before")
    @classmethod
    def _one_form(cls, data: Any) -> Any:
        # one form or the other, said before either is checked key by key (a missing
        # one is said after them, by _distinct: a key given under a typo'd name is
        # missing, and the typo, an unknown key, is what to say first)
        if isinstance(data, dict) and "base_stations" in data and (
                "base_station" in data or "nodes" in data):
            raise ValueError("base_stations: give either base_stations (each with its "
                             "nodes) or base_station and nodes, not both")
        return data

    _stations: list[StationConfig] = PrivateAttr(default_factory=list)

    @property
    def stations(self) -> list[StationConfig]:
        """Every base station, named: the one form is a list of one."""
        return self._stations

    @property
    def all_nodes(self) -> list[NodeEntry]:
        """Every node of every station."""
        return [node for station in self._stations for node in station.nodes]

    def _name_stations(self) -> None:
        if self.base_stations is None:
            assert self.base_station is not None and self.nodes is not None
            stations = [StationConfig(**self.base_station.model_dump(), nodes=self.nodes)]
        else:
            stations = self.base_stations
        self._stations = [station.model_copy(update={"name": station.name or
                                                     default_station_name(index)})
                          for index, station in enumerate(stations)]

    @field_validator("record", "lsl", mode="before")
    @classmethod
    def _bare_record(cls, value: Any) -> Any:
        # a ``record:`` (or ``lsl:``) with every key under it commented out is YAML's
        # null: it asks for the output, with the defaults, rather than silently for
        # none (leave it out)
        return {} if value is None else value

    @model_validator(mode="after")
    def _distinct(self) -> GatewayConfig:
        if self.base_stations is None:
            for key in ("base_station", "nodes"):
                if getattr(self, key) is None:
                    raise ValueError(f"{key}: required (or base_stations)")
        self._name_stations()
        self._distinct_stations()
        seen: set[int] = set()
        for index, node in enumerate(self.nodes or ()):
            if node.address in seen:
                raise ValueError(f"nodes[{index}].address: {node.address} is already "
                                 "configured")
            seen.add(node.address)
        if self.publish.endpoint == self.control.endpoint:
            raise ValueError("publish.endpoint and control.endpoint must differ")
        if (self.live is not None and self.metrics is not None
                and host_port(self.live.endpoint) == host_port(self.metrics.endpoint)):
            raise ValueError("live.endpoint and metrics.endpoint must differ")
        if self.curve is None and not is_loopback(self.control.endpoint):
            raise ValueError(f"control.endpoint: {self.control.endpoint} may be reachable "
                             "from other hosts, and control can write EEPROM and stop "
                             "streams: bind it to 127.0.0.1 or an ipc:// path, or "
                             "configure curve (see docs/operating.md, Security)")
        for where, station in self.placed_stations():
            try:
                ports.check_url(station.port, [n.address for n in station.nodes])
            except ValueError as error:
                raise ValueError(f"{where}.port: {error}") from None
        return self

    def placed_stations(self) -> list[tuple[str, StationConfig]]:
        """Each station with where it is in the file (for messages)."""
        if self.base_stations is None:
            return [("base_station", self.stations[0])]
        return [(f"base_stations[{i}]", s) for i, s in enumerate(self.stations)]

    def _distinct_stations(self) -> None:
        """A node address, a name and a port belong to one station each: a node is named
        by its address alone (topics, gx2ctl), a station by its name."""
        if self.base_stations is None:
            return
        names: dict[str, str] = {}
        serial_ports: dict[str, str] = {}
        owners: dict[int, str] = {}
        for where, station in self.placed_stations():
            label = f"{where} ({station.name})"
            if station.name in names:
                raise ValueError(f"{where}.name: {station.name!r} is also "
                                 f"{names[station.name]}'s name")
            names[station.name or ""] = where
            # sim:// and replay:// open nothing shared: each station its own
            if not station.port.startswith((ports.SIM_SCHEME, "replay://")):
                if station.port in serial_ports:
                    raise ValueError(f"{where}.port: {station.port} is also "
                                     f"{serial_ports[station.port]}'s port")
                serial_ports[station.port] = label
            for index, node in enumerate(station.nodes):
                if node.address in owners:
                    raise ValueError(f"{where}.nodes[{index}].address: node {node.address} "
                                     f"is also on {owners[node.address]}: an address is "
                                     "one node across the gateway")
                owners[node.address] = label


def load_config(path: str | Path) -> GatewayConfig:
    """Read and validate a gateway configuration; raises ConfigError (one line)."""
    return load_model(path, GatewayConfig)
