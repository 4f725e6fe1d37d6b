"""JSON Schemas of the published messages: a node's records, the gateway's status, marks,
and a node's frame (Foxglove's own FrameTransform, for the live view and recordings).

A recording's JSON channels each carry one (schema encoding ``jsonschema``): PlotJuggler
skips a channel without a schema ("Skipping MCAP channel with missing schema",
plotjuggler_plugins/DataLoadMCAP/dataload_mcap.cpp, 3.17) and Foxglove takes the
fields' types from it. A record's schema is made from the record table
(:mod:`aspp.records`): its fields' names, JSON types and fixed lengths (a 3-vector is 3
numbers, a matrix 3 rows of 3), each field's meaning and unit in its description, then
the fields every published record carries (docs/interface.md, section 4). NaN is
written as null (:mod:`gateway.common.jsontext`), so every float may be null.

Pure, and built once: a writer asks for a topic's schema when it first meets the topic.
"""

from __future__ import annotations

from functools import cache
from typing import Any

from aspp.fields import U8, Field
from aspp.frame import MAX_NODE, MIN_NODE
from aspp.records import BY_NAME, CommandSpec, all_specs, derived

from .topics import MARK_TOPIC, STATUS_TOPIC, is_frame, parse

Schema = dict[str, Any]

ENCODING = "jsonschema"
"""The schema encoding of the MCAP schema records (the MCAP spec's well-known name)."""
DRAFT = "https://json-schema.org/draft/2020-12/schema"
PREFIX = "gx2."
"""A record's schema is named ``gx2.<record>``; the gateway's own ``gx2.gateway.*``."""
STATUS_NAME = f"{PREFIX}gateway.status"
MARK_NAME = f"{PREFIX}gateway.mark"

_FLOAT: Schema = {"type": ["number", "null"]}
"""A float: null where the value was NaN."""
_NULL_IS_NAN = "null stands for NaN."


def _unsigned(largest: int) -> Schema:
    return {"type": "integer", "minimum": 0, "maximum": largest}


def _array(items: Schema, length: int) -> Schema:
    return {"type": "array", "items": items, "minItems": length, "maxItems": length}


def _described(schema: Schema, meaning: str, unit: str = "") -> Schema:
    text = f"{meaning} [{unit}]" if unit else meaning
    return {**schema, "description": text} if text else schema


def field_schema(field: Field) -> Schema:
    """One record field: its JSON type and shape, its meaning and unit."""
    kind = field.type
    shape = kind.shape
    if shape == "int":
        value = _unsigned(kind.max_int)
    elif shape == "float":
        value = dict(_FLOAT)
    elif shape == "vector":
        value = _array(_FLOAT, kind.items)
    elif shape == "matrix":
        value = _array(_array(_FLOAT, 3), 3)
    elif shape == "ints":
        value = _array(_unsigned(kind.max_int), kind.items)
    else:  # text: latin-1, one character a byte, trailing spaces and NULs stripped
        value = {"type": "string", "maxLength": kind.size}
    return _described(value, _meaning(field), field.unit)


def _meaning(field: Field) -> str:
    return f"{field.meaning}: {', '.join(field.elements)}" if field.elements else field.meaning


# the fields every published record carries besides its own (docs/interface.md, section
# 4; built in gateway.daemon.station.nodes.Node.tally), then a timed record's two; lqi and rssi
# are the packet's two link quality bytes (aspp.events.LINK_QUALITY: an unsigned and a
# signed byte)
_COMMON: tuple[tuple[str, Schema, str, str], ...] = (
    ("node", {"type": "integer", "minimum": MIN_NODE, "maximum": MAX_NODE},
     "the node's address", ""),
    ("seq", {"type": "integer", "minimum": 1}, "per node, +1 for each message published on "
     "that node's topics: a gap is a loss", ""),
    ("host_time", _FLOAT, "UNIX time when the packet's last byte was read", "s"),
    ("lqi", _unsigned(U8.max_int), "link quality", ""),
    ("rssi", {"type": "integer", "minimum": -128, "maximum": 127}, "signal strength", "dBm"),
)
_TIMED: tuple[tuple[str, Schema, str, str], ...] = (
    ("device_time", _FLOAT, "the node's timer in seconds, unwrapped across rollovers, so "
     "it never goes back", "s"),
    ("time", _FLOAT, "UNIX time when the sample was taken, on one clock for every node",
     "s"),
)
_STATION = _described({"type": "string"}, "the base station the record came through")


def record_schema(spec: CommandSpec) -> Schema:
    """The schema of ``spec``'s record as published (and recorded) on
    ``gx2/<address>/<record>``; ValueError for a command without a reply."""
    if spec.reply is None:
        raise ValueError(f"{spec.name} has no reply: nothing is published for it")
    added = derived(spec)
    properties = {f.name: field_schema(f) for f in (*spec.reply, *added)}
    properties["record"] = _described({"type": "string", "const": spec.name},
                                      "the record's name")
    properties["command"] = _described({"type": "integer", "const": spec.code},
                                       "the echo byte: the record's command byte")
    common = _COMMON + (_TIMED if spec.timed else ())
    for name, value, meaning, unit in common:
        properties[name] = _described(value, meaning, unit)
    required = [*spec.field_names, *(f.name for f in added), "record", "command",
                *(c[0] for c in common)]
    properties["station"] = _STATION  # (not required: a record may come without it)
    return {
        "$schema": DRAFT,
        "title": f"{PREFIX}{spec.name}",
        "description": f"0x{spec.code:02X} {spec.name}: {spec.title}, as gx2-gateway "
                       f"publishes it on gx2/<address>/{spec.name}; {_NULL_IS_NAN}",
        "type": "object",
        "properties": properties,
        "required": required,
        "additionalProperties": False,
    }


def _part(kind: str | list[str], meaning: str, required: tuple[str, ...] = (),
          **properties: Schema) -> Schema:
    """A part of the status: its type, what it is, and the keys every reader relies on
    (the rest may come and go: additional properties are allowed)."""
    schema: Schema = {"type": kind, "description": meaning}
    if properties:
        schema["properties"] = properties
    if required:
        schema["required"] = list(required)
    return schema


def status_schema() -> Schema:
    """The status (``gx2ctl --json status``, published on gx2/gateway/status): its
    top-level keys and their types; what is inside each part may grow."""
    node = _part("object", "one node", ("node",), node={"type": "integer"})
    address = {"type": "integer", "minimum": MIN_NODE, "maximum": MAX_NODE}
    heard = _part("object", "one address heard that is not configured",
                  ("address", "record", "rate_hz", "rssi", "lqi", "packets", "last_heard"),
                  address=_described(address, "the node's address"),
                  record=_described({"type": ["string", "null"]}, "the record it last "
                                    "sent since its last power-up; null before any"),
                  rate_hz=_described(_FLOAT, "the rate it streams at (from its timer); "
                                     "null while it does not stream", "Hz"),
                  rssi=_described(_FLOAT, "median of its last packets' RSSI", "dBm"),
                  lqi=_described(_FLOAT, "median of its last packets' LQI"),
                  packets={"type": "integer", "minimum": 1},
                  last_heard=_described(_FLOAT, "UNIX time of its last packet", "s"))
    return {
        "$schema": DRAFT,
        "title": STATUS_NAME,
        "description": "the gateway's status report, published every heartbeat_s and at "
                       f"once when the base station comes or goes; {_NULL_IS_NAN}",
        "type": "object",
        "properties": {
            "gateway": _part("object", "the gateway: version, uptime, endpoints, counts",
                             ("time",), time=_described(_FLOAT, "UNIX time of the report",
                                                        "s"),
                             version={"type": "string"}),
            "link": _part("object", "the (first) base station's serial link: port, state, "
                          "counts of what was read and discarded"),
            "stations": {"type": "array", "items": _part(
                "object", "one base station: its name, its link's fields (as link), "
                "its nodes' addresses and the addresses it heard that are not configured",
                ("name", "nodes", "heard"), name={"type": "string"},
                heard={"type": "array", "items": heard, "description": "by address"}),
                "description": "every base station, in the configuration's order"},
            "nodes": {"type": "array", "items": node, "description": "one map a node: "
                      "state, rates, losses, clock, health"},
            "recording": _part(["object", "null"], "the recorder; null without record:"),
            "replay": _part(["object", "null"], "the replay; null unless the port is "
                            "replay://"),
            "live": _part(["object", "null"], "the live view (Foxglove WebSocket): its "
                          "endpoint, viewers and channels; null without live:"),
            "lsl": _part(["object", "null"], "the Lab Streaming Layer outlets: their "
                         "streams, samples pushed, queued, dropped; null without lsl:"),
            "mqtt": _part(["object", "null"], "the MQTT output: its broker, whether it is "
                          "connected (and why not), messages sent, dropped (queue, "
                          "offline) and thinned by rate_hz; null without mqtt:"),
            "outputs": {"type": "object", "additionalProperties": _part(
                "object", "one output: take_failures, the messages it failed to take (a "
                "bug, contained: every other output still got them)", ("take_failures",),
                take_failures={"type": "integer", "minimum": 0}),
                "description": "each output given the published messages beside ZeroMQ "
                               "(live, recording, ...), by name, and frames (the nodes' "
                               "frames made for them)"},
        },
        "required": ["gateway", "link", "nodes", "recording", "replay"],
        "additionalProperties": False,
    }


_MARK: tuple[tuple[str, Schema, str, str], ...] = (
    ("text", {"type": "string"}, "what happened (one line)", ""),
    ("time", _FLOAT, "UNIX time the gateway took it, on the clock of every record's time",
     "s"),
    ("host_time", _FLOAT, "the same moment, as a record's host_time", "s"),
    ("nodes", {"type": "array", "items": {
        "type": "integer", "minimum": MIN_NODE, "maximum": MAX_NODE}},
     "the addresses it concerns; empty: the whole experiment", ""),
    ("fields", {"type": "object", "additionalProperties": {"type": "string"}},
     "what its maker said of it (gx2ctl mark --field KEY=VALUE: a trial's subject, "
     "condition ...); absent in a mark made before issue 44", ""),
)

Notes = dict[str, tuple[str, str]]
"""(meaning, unit) by field name: the schema's description with its unit kept apart."""


def record_notes(record: str) -> Notes:
    """What each field of ``record`` means and its unit, as its schema says: the fields
    every record carries (a timed record's two included), then the record's own (none
    for a record this version does not know). For tables that keep units apart: gx2ctl
    export's Parquet field metadata and .mat ``units``."""
    notes = {name: (meaning, unit) for name, _, meaning, unit in _COMMON + _TIMED}
    spec = BY_NAME.get(record)
    if spec is not None and spec.reply is not None:
        notes.update((f.name, (_meaning(f), f.unit)) for f in (*spec.reply, *derived(spec)))
    return notes


def mark_notes() -> Notes:
    """What each field of a mark means and its unit, as its schema says."""
    return {name: (meaning, unit) for name, _, meaning, unit in _MARK}


def mark_schema() -> Schema:
    """A mark (``gx2ctl mark``), published on gx2/gateway/mark."""
    return {
        "$schema": DRAFT,
        "title": MARK_NAME,
        "description": f"a mark made with gx2ctl mark; {_NULL_IS_NAN}",
        "type": "object",
        "properties": {name: _described(value, meaning, unit)
                       for name, value, meaning, unit in _MARK},
        "required": ["text", "time", "host_time", "nodes"],
        "additionalProperties": False,
    }


@cache
def _table() -> dict[str, tuple[str, Schema]]:
    """Every schema by what names its topic: a record's name, or the gateway's topic."""
    table = {spec.name: (f"{PREFIX}{spec.name}", record_schema(spec))
             for spec in all_specs() if spec.reply is not None}
    table[STATUS_TOPIC.decode()] = (STATUS_NAME, status_schema())
    table[MARK_TOPIC.decode()] = (MARK_NAME, mark_schema())
    return table


FRAME_NAME = "foxglove.FrameTransform"
"""The schema name by which Foxglove knows a frame transform, whatever its encoding."""


def frame_schema() -> Schema:
    """A node's orientation on gx2/<address>/frame: Foxglove's FrameTransform as its
    JSON encoding has it (a time as ``sec`` and ``nsec``), so the 3D panel draws it."""
    def xyz(*axes: str) -> Schema:
        return {"type": "object", "properties": {a: {"type": "number"} for a in axes},
                "required": list(axes)}
    return {
        "$schema": DRAFT,
        "title": FRAME_NAME,
        "description": "A transform between two reference frames in 3D space: a node's "
                       "orientation (its sensor frame in the earth frame, parent_frame_id) "
                       "at the sample's time, as gx2-gateway's live view and recordings "
                       "carry it on gx2/<address>/frame",
        "type": "object",
        "properties": {
            "timestamp": {"type": "object", "description": "Timestamp of transform",
                          "properties": {"sec": {"type": "integer", "minimum": 0},
                                         "nsec": {"type": "integer", "minimum": 0,
                                                  "maximum": 999_999_999}},
                          "required": ["sec", "nsec"]},
            "parent_frame_id": {"type": "string", "description": "Name of the parent frame"},
            "child_frame_id": {"type": "string", "description": "Name of the child frame"},
            "translation": {**xyz("x", "y", "z"),
                            "description": "Translation component of the transform"},
            "rotation": {**xyz("x", "y", "z", "w"),
                         "description": "Rotation component of the transform"},
        },
        "required": ["timestamp", "parent_frame_id", "child_frame_id", "translation",
                     "rotation"],
    }


def schema_for_topic(topic: str) -> tuple[str, Schema] | None:
    """The name and schema of what is published on ``topic``; None for a topic the
    gateway does not publish (a record it does not know). The schema is shared: do not
    change it."""
    if is_frame(topic):
        return FRAME_NAME, _frame()
    node = parse(topic)
    return _table().get(node[1] if node is not None else topic)


@cache
def _frame() -> Schema:
    return frame_schema()
