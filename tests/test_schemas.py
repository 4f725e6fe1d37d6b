"""The JSON Schemas of the published messages, checked against the contract's own list
of each record's fields (written out here, not read from the record table the schemas
are made from) and against payloads shaped as the gateway publishes them."""

from __future__ import annotations

import math

import pytest
from jsonschema import Draft202012Validator, ValidationError

from aspp.frame import encode_reply_packet
from aspp.records import all_specs, decode, encode
from gateway.common.jsontext import strict
from gateway.common.schemas import (
    ENCODING,
    mark_schema,
    record_schema,
    schema_for_topic,
    status_schema,
)
from gateway.daemon.config import NodeEntry
from gateway.daemon.station.nodes import Node

# docs/interface.md, sections 2 and 4: each record's fields, and the kinds they have
CONTRACT = {
    "raw_sensors": ("raw_accel", "raw_ang_rate", "timer"),
    "accel_angrate": ("accel", "ang_rate", "timer"),
    "delta_angle_velocity": ("delta_angle", "delta_velocity", "timer"),
    "continuous_mode": ("continuous_command", "timer"),
    "orientation": ("orientation", "timer"),
    "orientation_update": ("orientation_update", "timer"),
    "mag": ("mag", "timer"),
    "accel_angrate_orientation": ("accel", "ang_rate", "orientation", "timer"),
    "accel_bias": ("accel_bias", "timer"),
    "gyro_bias": ("gyro_bias", "timer"),
    "accel_angrate_mag": ("accel", "ang_rate", "mag", "timer"),
    "accel_angrate_mag_orientation": ("accel", "ang_rate", "mag", "orientation", "timer"),
    "capture_gyro_bias": ("gyro_bias", "timer"),
    "euler": ("roll", "pitch", "yaw", "timer"),
    "euler_angrate": ("roll", "pitch", "yaw", "ang_rate", "timer"),
    "store_nonvolatile": ("quantity", "timer"),
    "temperatures": ("temperature", "timer"),
    "stab_accel_angrate_mag": ("stab_accel", "ang_rate", "stab_mag", "timer"),
    "delta_angle_velocity_mag": ("delta_angle", "delta_velocity", "mag", "timer"),
    "eeprom_write": ("value",),
    "eeprom_read": ("value",),
    "firmware_version": ("version",),
    "device_id": ("selector", "text"),
    "built_in_test": ("test_config",),
}
# section 9: a record with an orientation matrix also carries its angles and quaternion
FROM_MATRIX = ("roll", "pitch", "yaw", "quaternion")
for _name, _fields in list(CONTRACT.items()):
    if "orientation" in _fields:
        CONTRACT[_name] = (*_fields, *FROM_MATRIX)
VECTORS = {"raw_accel", "raw_ang_rate", "accel", "ang_rate", "delta_angle", "delta_velocity",
           "mag", "accel_bias", "gyro_bias", "stab_accel", "stab_mag"}
MATRICES = {"orientation", "orientation_update"}
FLOATS = {"roll", "pitch", "yaw"}
INTEGERS = {"continuous_command", "quantity", "value", "version", "selector", "timer",
            "test_config"}
UNITS = {"accel": "g", "ang_rate": "rad/s", "mag": "gauss", "roll": "rad",
         "delta_velocity": "g*s", "timer": "ticks", "temperature": "A/D codes"}
COMMON = {"node": "integer", "record": "string", "command": "integer", "seq": "integer",
          "host_time": "number", "lqi": "integer", "rssi": "integer"}
TIMED = {"device_time": "number", "time": "number"}
SPECS = [spec for spec in all_specs() if spec.reply is not None]


def types(schema: dict) -> set[str]:
    kind = schema["type"]
    return {kind} if isinstance(kind, str) else set(kind)


def is_float(schema: dict) -> bool:
    """A number that may be null (NaN is written as null)."""
    return types(schema) == {"number", "null"}


def published(record: str, **fields: object) -> dict:
    """A record as the gateway publishes it (by nodes.Node.tally itself), then as
    recorded (JSON: tuples become lists, NaN null)."""
    raw = encode_reply_packet(76, encode(record, **fields))
    payload = Node(NodeEntry(address=76)).tally(raw, decode(raw, 7, len(raw) - 4), 1.7e9,
                                                100.0)
    return strict(payload)


def test_the_contract_lists_every_record_the_table_has() -> None:
    assert {spec.name for spec in SPECS} == set(CONTRACT)


@pytest.mark.parametrize("spec", SPECS, ids=lambda spec: spec.name)
def test_a_records_schema_names_every_field_the_contract_publishes(spec) -> None:
    schema = record_schema(spec)
    Draft202012Validator.check_schema(schema)
    properties = schema["properties"]
    expected = {**dict.fromkeys(CONTRACT[spec.name]), **COMMON,
                **(TIMED if "timer" in CONTRACT[spec.name] else {})}
    assert set(schema["required"]) == set(expected)
    assert set(properties) == set(expected) | {"station"}
    assert types(properties["station"]) == {"string"}
    assert schema["additionalProperties"] is False
    assert schema["title"] == f"gx2.{spec.name}"
    assert properties["record"]["const"] == spec.name
    assert properties["command"]["const"] == spec.code
    for name, kind in {**COMMON, **TIMED}.items():
        if name in properties:
            assert kind in types(properties[name]), name
    for name in CONTRACT[spec.name]:
        field = properties[name]
        assert field["description"], name
        if name in VECTORS:
            assert field["minItems"] == field["maxItems"] == 3 and is_float(field["items"])
        elif name in MATRICES:
            assert field["minItems"] == field["maxItems"] == 3
            row = field["items"]
            assert row["minItems"] == row["maxItems"] == 3 and is_float(row["items"])
        elif name in FLOATS:
            assert is_float(field)
        elif name in INTEGERS:
            assert types(field) == {"integer"}
        elif name == "quaternion":
            assert field["minItems"] == field["maxItems"] == 4 and is_float(field["items"])
            assert "w, x, y, z" in field["description"]
        elif name == "temperature":
            assert field["minItems"] == field["maxItems"] == 4
            assert types(field["items"]) == {"integer"}
            assert "accel, gyro_x, gyro_y, gyro_z" in field["description"]
        else:
            assert name == "text" and types(field) == {"string"}
        if name in UNITS:
            assert field["description"].endswith(f"[{UNITS[name]}]"), field["description"]


def test_the_gateways_own_schemas_are_valid_and_name_their_keys() -> None:
    status, mark = status_schema(), mark_schema()
    for schema in (status, mark):
        Draft202012Validator.check_schema(schema)
    assert set(status["properties"]) == {"gateway", "link", "stations", "nodes", "recording",
                                          "replay", "live", "lsl", "outputs",
                                          "mqtt"}
    assert types(status["properties"]["recording"]) == {"object", "null"}
    assert set(mark["required"]) == {"text", "time", "nodes", "host_time"}


def test_each_topic_has_its_schema_by_name_and_foreign_ones_none() -> None:
    assert ENCODING == "jsonschema"
    assert schema_for_topic("gx2/76/accel_angrate")[0] == "gx2.accel_angrate"
    assert schema_for_topic("gx2/760/euler")[1]["title"] == "gx2.euler"
    assert schema_for_topic("gx2/gateway/status")[0] == "gx2.gateway.status"
    assert schema_for_topic("gx2/gateway/mark")[0] == "gx2.gateway.mark"
    assert schema_for_topic("gx2/76/nonsense") is None
    assert schema_for_topic("gx2/76/stop_continuous") is None  # no reply: never published
    assert schema_for_topic("other/topic") is None
    assert schema_for_topic("gx2/76/euler") is schema_for_topic("gx2/77/euler")  # built once


def test_payloads_as_published_validate_nan_included_and_wrong_shapes_do_not() -> None:
    nan = math.nan
    samples = [
        published("accel_angrate_mag_orientation", accel=(0, 0, -1), ang_rate=(0, 0, 0.1),
                  mag=(nan, nan, nan), orientation=((1, 0, 0), (0, 1, 0), (0, 0, 1)),
                  timer=123),
        published("temperatures", temperature=(1, 2, 3, 4), timer=5),
        published("device_id", selector=1, text="2600 "),
        published("firmware_version", version=1106),
    ]
    for payload in samples:
        Draft202012Validator(schema_for_topic(f"gx2/76/{payload['record']}")[1]).validate(
            {**payload, "station": "usb0"})
    schema = schema_for_topic("gx2/76/accel_angrate_mag_orientation")[1]
    wrong = [{**samples[0], "accel": [0, 0]}, {**samples[0], "extra": 1},
             {k: v for k, v in samples[0].items() if k != "time"},
             {**samples[0], "orientation": [[1, 0, 0], [0, 1, 0]]}]
    for payload in wrong:
        with pytest.raises(ValidationError):
            Draft202012Validator(schema).validate(payload)
    Draft202012Validator(mark_schema()).validate(
        {"text": "tapped", "time": 1.7e9, "host_time": 1.7e9, "nodes": [76]})
