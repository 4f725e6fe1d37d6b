"""gx2-sim's configuration: a small YAML file, or the same keys from the command line.

```yaml
baudrate: 115200
seed: 1
first_write_failure: 0.3      # chance the first EEPROM write after power-up fails
line: {garbage: 0.01, bad_checksum: 0.0, false_header: 0.0, glue_ack: false, nack: 0.0}
nodes:
  - address: 76
    model: inertia-link       # or 3dm-gx2 (which has a magnetometer)
    stream: accel_angrate     # auto-start record (EEPROM 0xFCA6), or omit for polled
    motion: turn              # turn (about the vertical) or swing (and wobbling, 4 s)
    divider: 512              # 51200 / 512 = 100 Hz
    timer_start: 0.0          # seconds on the timer at power-up (215: near the wrap)
    ppm: null                 # its crystal's error (null: -30..+30 by address)
    phase_ms: 0.0             # its cycles start this long after power-up (all nodes
                              # power up together: where its samples fall against others')
    gyro: ADXRS610            # rate sensor model (its temperature output)
    gyro_bias_error: [0.002, -0.001, 0.0015]   # rad/s: what a bias capture estimates
    accel_noise: 0.002        # g, standard deviation of each accelerometer
    rate_noise: 0.005         # rad/s, the same for each rate sensor
    bit_faults: [rate_y]      # outputs that fail the built-in test (accel_x .. rate_z)
    radio: {in_range: true, command_loss: 0.0, data_loss: 0.0, stop_loss: 0.0,
            lqi: 200, rssi: -45, jitter_ms: 0.5}   # jitter: mean of the random delay
    powered: true             # false: present but off, answering nothing, until
                              # 'gx2-sim power 76 on' (it powers up: a discovery packet)
```

Or several base stations, each behind its own pty with its own nodes and faults (the
keys above, per station), instead of those keys at the top level:

```yaml
base_stations:
  - name: north               # required: [A-Za-z0-9][A-Za-z0-9_-]{0,31}, as the gateway's
    link: /tmp/gx2-north      # optional: a stable symlink to this station's pty
    line: {garbage: 0.01}
    nodes: [{address: 76, stream: accel_angrate}]
  - name: south
    nodes: [{address: 78}]
```
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any
from urllib.parse import parse_qsl, urlsplit

from pydantic import Field, ValidationError, field_validator, model_validator

from aspp.records import checked
from aspp.temperature import DEFAULT_GYRO, gyro_model
from aspp.timing import DEFAULT_DIVIDER, MAX_DIVIDER, MIN_DIVIDER
from gateway.common.strict import Strict, describe
from gateway.common.topics import STATION_NAME
from gateway.common.yamlfile import ConfigError, read_mapping

from .base_station import BUFFER_BYTES, LineFaults, RadioLink
from .node import GX2, INERTIA_LINK, NodeSettings
from .physics import MOTIONS

Probability = Field(default=0.0, ge=0.0, le=1.0)


class RadioConfig(Strict):
    in_range: bool = True
    command_loss: float = Probability
    data_loss: float = Probability
    stop_loss: float = Probability
    lqi: int = Field(default=200, ge=0, le=255)
    rssi: int = Field(default=-45, ge=-128, le=127)
    jitter_ms: float = Field(default=RadioLink.jitter * 1000, ge=0.0, le=100.0)

    def build(self) -> RadioLink:
        fields = self.model_dump()
        jitter = fields.pop("jitter_ms") / 1000
        return RadioLink(**fields, jitter=jitter)


class LineConfig(Strict):
    garbage: float = Probability
    bad_checksum: float = Probability
    false_header: float = Probability
    glue_ack: bool = False
    nack: float = Probability
    buffer_bytes: int | None = Field(default=BUFFER_BYTES, gt=0)
    """The base station's output buffer (null: without bound)."""
    throughput: float = Field(default=1.0, gt=0.0, le=1.0)
    """The share of the baud rate its output reaches with a backlog (gaps between
    packets below 1)."""

    def build(self) -> LineFaults:
        return LineFaults(**self.model_dump())


class SimNodeEntry(Strict):
    address: int = Field(ge=1, le=65534)
    model: str = INERTIA_LINK
    stream: str | None = None
    divider: int = Field(default=DEFAULT_DIVIDER, ge=MIN_DIVIDER, le=MAX_DIVIDER)
    timer_start: float = Field(default=0.0, ge=0.0)
    ppm: float | None = Field(default=None, ge=-1000.0, le=1000.0)
    phase_ms: float = Field(default=0.0, ge=0.0, le=1000.0)
    serial: str = Field(default="", max_length=16)
    gyro: str = DEFAULT_GYRO
    gyro_bias_error: list[float] = Field(default=[0.0, 0.0, 0.0], min_length=3, max_length=3)
    accel_noise: float = Field(default=0.0, ge=0.0, le=1.0)
    rate_noise: float = Field(default=0.0, ge=0.0, le=1.0)
    bit_faults: list[str] = Field(default_factory=list)
    motion: str = "turn"
    radio: RadioConfig = RadioConfig()
    powered: bool = True

    @field_validator("motion")
    @classmethod
    def _known_motion(cls, value: str) -> str:
        if value not in MOTIONS:
            raise ValueError(f"must be {' or '.join(MOTIONS)}, not {value!r}")
        return value

    @field_validator("gyro")
    @classmethod
    def _known_gyro(cls, value: str) -> str:
        gyro_model(value)
        return value

    @field_validator("bit_faults")
    @classmethod
    def _known_outputs(cls, values: list[str]) -> list[str]:
        known = [f"{o}_{a}" for o in ("accel", "rate") for a in "xyz"]
        for value in values:
            if value not in known:
                raise ValueError(f"{value!r} is not one of {', '.join(known)}")
        return values

    @field_validator("model")
    @classmethod
    def _known_model(cls, value: str) -> str:
        if value not in (INERTIA_LINK, GX2):
            raise ValueError(f"must be {INERTIA_LINK} or {GX2}, not {value!r}")
        return value

    @field_validator("stream")
    @classmethod
    def _streamable(cls, value: str | None) -> str | None:
        return None if value is None else checked(value, streamable=True).name

    def build(self) -> NodeSettings:
        return NodeSettings(address=self.address, model=self.model, stream=self.stream,
                            divider=self.divider, timer_start=self.timer_start,
                            ppm=self.ppm, phase=self.phase_ms / 1000,
                            serial=self.serial, gyro=self.gyro,
                            gyro_bias_error=tuple(self.gyro_bias_error),  # type: ignore[arg-type]
                            accel_noise=self.accel_noise, rate_noise=self.rate_noise,
                            bit_faults=frozenset(self.bit_faults),
                            motion=MOTIONS[self.motion], powered=self.powered)


class SimConfig(Strict):
    baudrate: int = Field(default=115200, ge=1200, le=4_000_000)
    seed: int = 1
    first_write_failure: float = Probability
    line: LineConfig = LineConfig()
    nodes: list[SimNodeEntry] = Field(default_factory=list)

    @model_validator(mode="after")
    def _unique_addresses(self) -> SimConfig:
        seen: set[int] = set()
        for node in self.nodes:
            if node.address in seen:
                raise ValueError(f"node address {node.address} appears twice")
            seen.add(node.address)
        return self


class SimStationConfig(SimConfig):
    """One of several base stations (``base_stations:``): its own pty, nodes and faults."""

    name: str = Field(pattern=STATION_NAME)
    link: str | None = Field(default=None, min_length=1)
    """A stable symlink to this station's pty (relative: to the working directory)."""
    nodes: list[SimNodeEntry] = Field(min_length=1)


class SimStationsConfig(Strict):
    """Several base stations served by one gx2-sim, each from its own thread."""

    base_stations: list[SimStationConfig] = Field(min_length=1)

    @model_validator(mode="before")
    @classmethod
    def _one_form(cls, data: Any) -> Any:
        # said before the keys are checked one by one: "unknown key" would not say why
        if isinstance(data, dict):
            single = [key for key in SimConfig.model_fields if key in data]
            if single:
                raise ValueError(f"{single[0]}: give either base_stations (each with its "
                                 "own nodes, line faults, seed...) or the one base station's "
                                 f"keys ({', '.join(SimConfig.model_fields)}), not both")
        return data

    @model_validator(mode="after")
    def _distinct(self) -> SimStationsConfig:
        # as the gateway's base_stations: a node is named by its address alone (topics,
        # gx2ctl), so one address is one node across every station; a name and a link
        # belong to one station each
        names: dict[str, str] = {}
        links: dict[str, str] = {}
        owners: dict[int, str] = {}
        for index, station in enumerate(self.base_stations):
            where = f"base_stations[{index}]"
            label = f"{where} ({station.name})"
            if station.name in names:
                raise ValueError(f"{where}.name: {station.name!r} is also "
                                 f"{names[station.name]}'s name")
            names[station.name] = where
            if station.link is not None:
                link = os.path.abspath(station.link)
                if link in links:
                    raise ValueError(f"{where}.link: {station.link} is also "
                                     f"{links[link]}'s link")
                links[link] = label
            for number, node in enumerate(station.nodes):
                if node.address in owners:
                    raise ValueError(f"{where}.nodes[{number}].address: node {node.address} "
                                     f"is also on {owners[node.address]}: an address is "
                                     "one node across the base stations")
                owners[node.address] = label
        return self


def load_sim_config(path: str | Path) -> SimConfig | SimStationsConfig:
    """The file's one base station, or its ``base_stations:``; ConfigError (one line)."""
    data = read_mapping(path)
    model: type[SimConfig | SimStationsConfig] = (
        SimStationsConfig if "base_stations" in data else SimConfig)
    try:
        return model.model_validate(data)
    except ValidationError as error:
        raise ConfigError(describe(error, str(path), model=model)) from None


_URL_KEYS = {"line": {"garbage", "bad_checksum", "false_header", "glue_ack", "nack",
                      "buffer_bytes", "throughput"},
             "radio": {"command_loss", "data_loss", "stop_loss"},
             "node": {"motion"},
             "top": {"seed", "first_write_failure"}}


def _extra_nodes(value: str) -> dict[int, str | None]:
    """``extra=81:accel_angrate,82``: addresses, each with the record it streams from
    power-up or none; ValueError (one line) for anything else."""
    extra: dict[int, str | None] = {}
    for item in filter(None, (part.strip() for part in value.split(","))):
        address, _, record = item.partition(":")
        try:
            extra[int(address)] = record.strip() or None
        except ValueError:
            raise ValueError(f"sim:// extra={value!r}: not a list of ADDRESS or "
                             "ADDRESS:RECORD (e.g. extra=81:accel_angrate,82)") from None
    return extra


def from_url(url: str, nodes: list[int]) -> SimConfig:
    """The simulator a gateway's ``port: sim://?...`` names, for ``nodes``, and the
    ``extra`` nodes the gateway is not configured for (``extra=81:accel_angrate,82``:
    each streaming that record from power-up, or nothing); ValueError with a one-line
    message for anything it cannot use. Nothing is started here, so ``gx2-gateway
    --check`` runs the same validation as start-up."""
    parts = urlsplit(url)
    if parts.scheme != "sim" or parts.netloc or parts.path not in ("", "/"):
        raise ValueError(f"{url!r}: sim:// takes only query parameters, "
                         "e.g. sim://?data_loss=0.05")
    groups: dict[str, dict[str, str]] = {"line": {}, "radio": {}, "node": {}, "top": {}}
    out_of_range: set[int] = set()
    extra: dict[int, str | None] = {}
    for key, value in parse_qsl(parts.query, keep_blank_values=True):
        if key == "extra":
            extra.update(_extra_nodes(value))
            continue
        if key == "out_of_range":
            try:
                out_of_range.update(int(v) for v in value.split(",") if v.strip())
            except ValueError:
                raise ValueError(f"sim:// out_of_range={value!r}: not a list of node "
                                 "addresses") from None
            continue
        group = next((g for g, keys in _URL_KEYS.items() if key in keys), None)
        if group is None:
            known = sorted(set().union(*_URL_KEYS.values()) | {"out_of_range", "extra"})
            raise ValueError(f"unknown sim:// parameter {key!r}; known: {', '.join(known)}")
        groups[group][key] = value
    if out_of_range - set(nodes):
        raise ValueError(f"sim:// out_of_range names node {min(out_of_range - set(nodes))}, "
                         "which is not configured")
    if set(extra) & set(nodes):
        raise ValueError(f"sim:// extra names node {min(set(extra) & set(nodes))}, which is "
                         "configured: extra nodes are those the gateway is not configured "
                         "for")
    try:
        return SimConfig.model_validate({  # query values are text: convert them
            "line": groups["line"], **groups["top"],
            "nodes": [{"address": a, **groups["node"],
                       "radio": {"in_range": a not in out_of_range, **groups["radio"]}}
                      for a in nodes]
                     + [{"address": a, "stream": record, **groups["node"],
                         "radio": groups["radio"]} for a, record in extra.items()]},
            strict=False)
    except ValidationError as error:
        raise ValueError(describe(error, "sim://")) from None
