"""The record table: it matches the reference's sizes, its names are the contract's,
and the copy in docs/interface.md is generated from it."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from aspp.errors import CommandError, RecordError
from aspp.records import BY_CODE, STREAMABLE, all_specs, decode, encode, lookup, markdown_table

# (command, record name, wired reply length from the reference including its 2-byte
# checksum, contract fields). 0xFB: the reference says 8, its fields total 4.
REFERENCE = [
    (0xC1, "raw_sensors", 31, "raw_accel raw_ang_rate timer"),
    (0xC2, "accel_angrate", 31, "accel ang_rate timer"),
    (0xC3, "delta_angle_velocity", 31, "delta_angle delta_velocity timer"),
    (0xC4, "continuous_mode", 8, "continuous_command timer"),
    (0xC5, "orientation", 43, "orientation timer"),
    (0xC6, "orientation_update", 43, "orientation_update timer"),
    (0xC7, "mag", 19, "mag timer"),
    (0xC8, "accel_angrate_orientation", 67, "accel ang_rate orientation timer"),
    (0xC9, "accel_bias", 19, "accel_bias timer"),
    (0xCA, "gyro_bias", 19, "gyro_bias timer"),
    (0xCB, "accel_angrate_mag", 43, "accel ang_rate mag timer"),
    (0xCC, "accel_angrate_mag_orientation", 79, "accel ang_rate mag orientation timer"),
    (0xCD, "capture_gyro_bias", 19, "gyro_bias timer"),
    (0xCE, "euler", 19, "roll pitch yaw timer"),
    (0xCF, "euler_angrate", 31, "roll pitch yaw ang_rate timer"),
    (0xD0, "store_nonvolatile", 9, "quantity timer"),
    (0xD1, "temperatures", 15, "temperature timer"),
    (0xD2, "stab_accel_angrate_mag", 43, "stab_accel ang_rate stab_mag timer"),
    (0xD3, "delta_angle_velocity_mag", 43, "delta_angle delta_velocity mag timer"),
    (0xE4, "eeprom_write", 5, "value"),
    (0xE5, "eeprom_read", 5, "value"),
    (0xE9, "firmware_version", 7, "version"),
    (0xEA, "device_id", 20, "selector text"),
    (0xFA, "stop_continuous", None, ""),
    (0xFB, "built_in_test", 4, "test_config"),
]


@pytest.mark.parametrize(("code", "name", "wired", "fields"), REFERENCE,
                         ids=[r[1] for r in REFERENCE])
def test_table_matches_reference_and_contract(code, name, wired, fields):
    spec = lookup(code)
    assert spec.name == name and lookup(name) is spec
    assert spec.reply_size == (None if wired is None else wired - 2)
    assert " ".join(spec.field_names) == fields


def test_table_has_exactly_the_reference_commands():
    assert sorted(BY_CODE) == [r[0] for r in REFERENCE]
    assert STREAMABLE == {s.code for s in all_specs() if s.streamable}
    assert 0xC4 not in STREAMABLE and 0xFA not in STREAMABLE


def test_the_documented_record_table_is_generated_from_the_table():
    interface = (Path(__file__).parents[2] / "docs" / "interface.md").read_text()
    block = re.search(r"<!-- records:begin -->\n(.*?)\n<!-- records:end -->", interface,
                      re.S)
    assert block, "docs/interface.md lost its records section"
    assert block.group(1) == markdown_table(), "regenerate the table: python -m aspp"


@pytest.mark.parametrize("payload", [
    b"", b"\x42", b"\xfa", b"\xc2" + bytes(27), b"\xc2" + bytes(29), b"\xe5\x00",
], ids=["empty", "unknown", "no-reply", "short", "long", "eeprom-short"])
def test_decode_refuses_the_wrong_bytes(payload):
    with pytest.raises(RecordError):
        decode(payload)


@pytest.mark.parametrize("payload", [
    b"", b"\x42", b"\xfa", b"\xc2" + bytes(27), b"\xc2" + bytes(29), b"\xe5\x00",
], ids=["empty", "unknown", "no-reply", "short", "long", "eeprom-short"])
def test_decode_in_place_refuses_the_same_bytes(payload):
    """decode(data, start, stop) reads data[start:stop] and nothing around it."""
    framed = b"\xc2" * 7 + payload + b"\xc2" * 4
    with pytest.raises(RecordError):
        decode(framed, 7, 7 + len(payload))


def test_decode_in_place_is_decode_of_the_slice():
    payload = encode("accel_angrate_orientation", accel=(0.5, 0, -1), ang_rate=(0, 0.1, 0),
                     orientation=((1, 0, 0), (0, 1, 0), (0, 0, 1)), timer=77)
    framed = b"\xaa\x07\x00\x00\x4c" + payload + b"\x01\x02"
    assert decode(framed, 5, 5 + len(payload)) == decode(payload)
    with pytest.raises(RecordError):  # a stop past the end is the end, never a misread
        decode(framed[:5 + len(payload) - 1], 5, 5 + len(payload))


def test_built_in_test_reply_may_run_long():
    assert decode(b"\xfb\x10")["test_config"] == 0x10
    assert decode(b"\xfb\x10\x00\x00\x00\x00")["test_config"] == 0x10


def test_record_access_and_text_stripping():
    rec = decode(encode("device_id", selector=1, text="4200-1076"))
    assert rec.name == "device_id" and rec.command == 0xEA and rec.timer is None
    assert rec.as_dict() == {"selector": 1, "text": "4200-1076"}
    padded = b"\xea\x02" + b"3DM-GX2\x00\x00  \x00\x00\x00\x00\x00"
    assert decode(padded)["text"] == "3DM-GX2"
    with pytest.raises(KeyError, match="no field 'accel'"):
        rec["accel"]


def test_nan_survives_and_compares_with_same_as():
    payload = encode("mag", mag=(math.nan,) * 3, timer=7)
    rec = decode(payload)
    assert all(math.isnan(v) for v in rec["mag"]) and rec.timer == 7
    assert rec.same_as(decode(payload))
    assert not rec.same_as(decode(encode("mag", mag=(0.0, math.nan, 0.0), timer=7)))


@pytest.mark.parametrize(("record", "fields", "names"), [
    ("euler", {"roll": 0, "pitch": 0, "yaw": 0}, "timer"),
    ("euler", {"roll": 0, "pitch": 0, "yaw": 0, "timer": 1, "speed": 2}, "speed"),
    ("accel_angrate", {"accel": (1, 2), "ang_rate": (0, 0, 0), "timer": 0}, "accel"),
    ("device_id", {"selector": 0, "text": "x" * 17}, "text"),
    ("temperatures", {"temperature": (1, 2, 3, 70000), "timer": 0}, "temperature[3]"),
    ("eeprom_read", {"value": -1}, "value"),
    ("stop_continuous", {}, "no reply"),
])
def test_encode_names_the_bad_field(record, fields, names):
    with pytest.raises(CommandError, match=re.escape(names)):
        encode(record, **fields)


def test_a_record_is_a_record_not_a_tuple():
    """Record is a NamedTuple for speed; it still behaves as a record: equal only to a
    record, fields looked up by any str (a StrEnum too), ``in`` asks for a field."""
    from enum import StrEnum

    class Names(StrEnum):
        TIMER = "timer"

    rec = decode(encode("euler", roll=0.1, pitch=0.2, yaw=0.3, timer=42))
    assert rec == decode(encode("euler", roll=0.1, pitch=0.2, yaw=0.3, timer=42))
    assert rec != (rec.spec, rec.values) and (rec.spec, rec.values) != rec
    assert hash(rec) == hash(decode(encode("euler", roll=0.1, pitch=0.2, yaw=0.3,
                                           timer=42)))
    assert rec[Names.TIMER] == 42 == rec.timer
    assert "yaw" in rec and "accel" not in rec
    with pytest.raises(KeyError):
        rec["accel"]
