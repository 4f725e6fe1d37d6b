"""Golden vectors: every command and reply record worked out by hand from the reference.

The expected bytes here are a second, independent reading of the 3DM-GX2 protocol
reference (seeds/000_3fb2063450b23559.txt) and of CONTRACT.md sections 1 and 2: hex
literals with their checksum arithmetic, and reply records laid out field by field from
the reference's byte tables with ``struct.pack`` (standard library, not aspp). Nothing
expected is produced by aspp's own table or encoders, so a mistake in either reading
makes a test fail.

Sums in the comments are hexadecimal. The command packet header sum for node 76 is
0B+00+00+4C+len+00 = 0x57+len; for node 0x1234 it is 0x51+len; for 0xFFFE 0x208+len.
"""

from __future__ import annotations

import math
import struct

import pytest

from aspp import commands, records
from aspp.decoder import Decoder
from aspp.errors import PacketError, RecordError
from aspp.events import Ack, Frame, Nack, PingOk, Reply
from aspp.frame import (
    checksum,
    decode_command_packet,
    encode_command_packet,
    encode_ping,
    encode_reply_packet,
)

# --- independent restatement of the reference's framing ---------------------------------


def _sum16(data: bytes) -> int:
    """The reference's checksum: the sum of the bytes, rolling over from 65535 to 0."""
    total = 0
    for byte in data:
        total = (total + byte) % 65536
    return total


def _command_packet(node: int, command: bytes) -> bytes:
    """AA 0B 00 <addr MSB> <addr LSB> <n+1> 00 <command> <ck MSB> <ck LSB>."""
    body = bytes([0x0B, 0x00, node >> 8, node & 0xFF, len(command) + 1, 0x00]) + command
    return b"\xAA" + body + _sum16(body).to_bytes(2, "big")


def _reply_packet(node: int, record: bytes, lqi: int, rssi_byte: int) -> bytes:
    """AA 07 00 <addr> <m+1> 00 <m record bytes> LQI RSSI <ck>; ck never covers
    SOP, LQI or RSSI."""
    body = bytes([0x07, 0x00, node >> 8, node & 0xFF, len(record) + 1, 0x00]) + record
    return b"\xAA" + body + bytes([lqi, rssi_byte]) + _sum16(body).to_bytes(2, "big")


def _f32(*values: float) -> bytes:
    """Big-endian IEEE-754 single floats, in the order given."""
    return b"".join(struct.pack(">f", v) for v in values)


def _u32(value: int) -> bytes:
    return value.to_bytes(4, "big")


def _u16(*values: int) -> bytes:
    return b"".join(v.to_bytes(2, "big") for v in values)


def _rec(echo: int, *parts: bytes) -> bytes:
    """A wired reply record without its checksum: the echo byte, then the fields."""
    return bytes([echo]) + b"".join(parts)


def _plain(value: object) -> object:
    """Tuples and lists alike as lists, so shapes compare, not container types."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    return value


def _hex(text: str) -> bytes:
    return bytes.fromhex(text)


# --- 1. host to node: every command's bytes and its full ASPP command packet ------------

COMMAND_VECTORS = [
    # id, builder, command bytes, arguments as the bytes carry them, node, packet
    pytest.param(lambda: commands.poll(0xC1), "C1", {}, 76,
                 "AA 0B 00 00 4C 02 00 C1 01 1A",  # 0x59 + C1 = 0x011A
                 id="0xC1-raw_sensors"),
    pytest.param(lambda: commands.poll("accel_angrate"), "C2", {}, 76,
                 "AA 0B 00 00 4C 02 00 C2 01 1B",  # 0x59 + C2 = 0x011B
                 id="0xC2-accel_angrate"),
    pytest.param(lambda: commands.poll(0xC3), "C3", {}, 0x1234,
                 "AA 0B 00 12 34 02 00 C3 01 16",  # 0x53 + C3 = 0x0116
                 id="0xC3-delta_angle_velocity"),
    pytest.param(lambda: commands.set_continuous("accel_angrate"), "C4 C1 29 C2",
                 {"continuous_command": 0xC2}, 76,
                 "AA 0B 00 00 4C 05 00 C4 C1 29 C2 02 CC",  # 0x5C+C4+C1+29+C2 = 0x02CC
                 id="0xC4-set_continuous"),
    pytest.param(lambda: commands.set_continuous(0xCE), "C4 C1 29 CE",
                 {"continuous_command": 0xCE}, 76,
                 "AA 0B 00 00 4C 05 00 C4 C1 29 CE 02 D8",  # 0x5C+C4+C1+29+CE = 0x02D8
                 id="0xC4-set_continuous-euler"),
    pytest.param(commands.stop_continuous_long, "C4 C1 29 00",
                 {"continuous_command": 0}, 76,
                 "AA 0B 00 00 4C 05 00 C4 C1 29 00 02 0A",  # 0x5C+C4+C1+29+00 = 0x020A
                 id="0xC4-stop_continuous_long"),
    pytest.param(lambda: commands.poll(0xC5), "C5", {}, 76,
                 "AA 0B 00 00 4C 02 00 C5 01 1E",  # 0x59 + C5 = 0x011E
                 id="0xC5-orientation"),
    pytest.param(lambda: commands.poll(0xC6), "C6", {}, 76,
                 "AA 0B 00 00 4C 02 00 C6 01 1F",  # 0x59 + C6 = 0x011F
                 id="0xC6-orientation_update"),
    pytest.param(lambda: commands.poll("mag"), "C7", {}, 76,
                 "AA 0B 00 00 4C 02 00 C7 01 20",  # 0x59 + C7 = 0x0120
                 id="0xC7-mag"),
    pytest.param(lambda: commands.poll(0xC8), "C8", {}, 0x1234,
                 "AA 0B 00 12 34 02 00 C8 01 1B",  # 0x53 + C8 = 0x011B
                 id="0xC8-accel_angrate_orientation"),
    # 0.5 = 3F000000, -1.0 = BF800000, 2.0 = 40000000
    pytest.param(lambda: commands.write_accel_bias((0.5, -1.0, 2.0)),
                 "C9 B7 44 3F 00 00 00 BF 80 00 00 40 00 00 00",
                 {"accel_bias": (0.5, -1.0, 2.0)}, 76,
                 # 0x67 + C9+B7+44 + 3F + BF+80 + 40 = 0x03E9
                 "AA 0B 00 00 4C 10 00 C9 B7 44 3F 00 00 00 BF 80 00 00 40 00 00 00 03 E9",
                 id="0xC9-write_accel_bias"),
    # 0.25 = 3E800000, 0.0 = 00000000, -0.125 = BE000000
    pytest.param(lambda: commands.write_gyro_bias((0.25, 0.0, -0.125)),
                 "CA 12 A5 3E 80 00 00 00 00 00 00 BE 00 00 00",
                 {"gyro_bias": (0.25, 0.0, -0.125)}, 76,
                 # 0x67 + CA+12+A5 + 3E+80 + BE = 0x0364
                 "AA 0B 00 00 4C 10 00 CA 12 A5 3E 80 00 00 00 00 00 00 BE 00 00 00 03 64",
                 id="0xCA-write_gyro_bias"),
    pytest.param(lambda: commands.poll(0xCB), "CB", {}, 76,
                 "AA 0B 00 00 4C 02 00 CB 01 24",  # 0x59 + CB = 0x0124
                 id="0xCB-accel_angrate_mag"),
    pytest.param(lambda: commands.poll(0xCC), "CC", {}, 76,
                 "AA 0B 00 00 4C 02 00 CC 01 25",  # 0x59 + CC = 0x0125
                 id="0xCC-accel_angrate_mag_orientation"),
    # 10000 ms = 0x2710
    pytest.param(lambda: commands.capture_gyro_bias(10000), "CD C1 29 27 10",
                 {"sampling_time": 10000}, 76,
                 "AA 0B 00 00 4C 06 00 CD C1 29 27 10 02 4B",  # 0x5D+CD+C1+29+27+10 = 0x024B
                 id="0xCD-capture_gyro_bias"),
    pytest.param(lambda: commands.poll("euler"), "CE", {}, 0x1234,
                 "AA 0B 00 12 34 02 00 CE 01 21",  # 0x53 + CE = 0x0121
                 id="0xCE-euler"),
    pytest.param(lambda: commands.poll(0xCF), "CF", {}, 76,
                 "AA 0B 00 00 4C 02 00 CF 01 28",  # 0x59 + CF = 0x0128
                 id="0xCF-euler_angrate"),
    pytest.param(lambda: commands.store_nonvolatile(2), "D0 C1 29 00 02",
                 {"quantity": 2}, 76,
                 "AA 0B 00 00 4C 06 00 D0 C1 29 00 02 02 19",  # 0x5D+D0+C1+29+00+02 = 0x0219
                 id="0xD0-store_nonvolatile"),
    pytest.param(lambda: commands.store_nonvolatile(1), "D0 C1 29 00 01",
                 {"quantity": 1}, 76,
                 "AA 0B 00 00 4C 06 00 D0 C1 29 00 01 02 18",  # 0x5D+D0+C1+29+00+01 = 0x0218
                 id="0xD0-store_nonvolatile-accel"),
    pytest.param(lambda: commands.poll(0xD1), "D1", {}, 76,
                 "AA 0B 00 00 4C 02 00 D1 01 2A",  # 0x59 + D1 = 0x012A
                 id="0xD1-temperatures"),
    pytest.param(lambda: commands.poll(0xD2), "D2", {}, 76,
                 "AA 0B 00 00 4C 02 00 D2 01 2B",  # 0x59 + D2 = 0x012B
                 id="0xD2-stab_accel_angrate_mag"),
    pytest.param(lambda: commands.poll(0xD3), "D3", {}, 0x1234,
                 "AA 0B 00 12 34 02 00 D3 01 26",  # 0x53 + D3 = 0x0126
                 id="0xD3-delta_angle_velocity_mag"),
    # E4: C1 29 00, address, value: the reference's 7 data bytes
    pytest.param(lambda: commands.write_eeprom(0xFCA2, 512), "E4 C1 29 00 FC A2 02 00",
                 {"address": 0xFCA2, "value": 512}, 76,
                 # 0x60 + E4+C1+29+00 + FC+A2 + 02+00 = 0x03CE
                 "AA 0B 00 00 4C 09 00 E4 C1 29 00 FC A2 02 00 03 CE",
                 id="0xE4-write_eeprom"),
    pytest.param(lambda: commands.set_divider(512), "E4 C1 29 00 FC A2 02 00",
                 {"address": 0xFCA2, "value": 512}, 76,
                 "AA 0B 00 00 4C 09 00 E4 C1 29 00 FC A2 02 00 03 CE",  # as above
                 id="0xE4-set_divider-100Hz"),
    # auto-start word: MSB 0x80 for a wireless node, LSB the record
    pytest.param(lambda: commands.set_auto_start("accel_angrate"),
                 "E4 C1 29 00 FC A6 80 C2", {"address": 0xFCA6, "value": 0x80C2}, 76,
                 # 0x60 + E4+C1+29+00 + FC+A6 + 80+C2 = 0x0512
                 "AA 0B 00 00 4C 09 00 E4 C1 29 00 FC A6 80 C2 05 12",
                 id="0xE4-set_auto_start"),
    pytest.param(lambda: commands.set_auto_start(None),
                 "E4 C1 29 00 FC A6 00 00", {"address": 0xFCA6, "value": 0}, 76,
                 # 0x60 + E4+C1+29+00 + FC+A6 + 00+00 = 0x03D0
                 "AA 0B 00 00 4C 09 00 E4 C1 29 00 FC A6 00 00 03 D0",
                 id="0xE4-set_auto_start-off"),
    pytest.param(lambda: commands.read_eeprom(0xFCA2), "E5 00 FC A2",
                 {"address": 0xFCA2}, 0xFFFE,
                 "AA 0B 00 FF FE 05 00 E5 00 FC A2 04 90",  # 0x20D+E5+00+FC+A2 = 0x0490
                 id="0xE5-read_eeprom"),
    pytest.param(commands.firmware_version, "E9", {}, 76,
                 "AA 0B 00 00 4C 02 00 E9 01 42",  # 0x59 + E9 = 0x0142
                 id="0xE9-firmware_version"),
    pytest.param(lambda: commands.device_id(1), "EA 01", {"selector": 1}, 76,
                 "AA 0B 00 00 4C 03 00 EA 01 01 45",  # 0x5A + EA + 01 = 0x0145
                 id="0xEA-device_id"),
    pytest.param(lambda: commands.device_id(3), "EA 03", {"selector": 3}, 0x1234,
                 "AA 0B 00 12 34 03 00 EA 03 01 41",  # 0x54 + EA + 03 = 0x0141
                 id="0xEA-device_id-options"),
    pytest.param(commands.stop_continuous, "FA", {}, 76,
                 "AA 0B 00 00 4C 02 00 FA 01 53",  # 0x59 + FA = 0x0153
                 id="0xFA-stop_continuous"),
    pytest.param(lambda: commands.built_in_test(0x14), "FB C1 29 14",
                 {"test_config": 0x14}, 76,
                 "AA 0B 00 00 4C 05 00 FB C1 29 14 02 55",  # 0x5C+FB+C1+29+14 = 0x0255
                 id="0xFB-built_in_test"),
    pytest.param(lambda: commands.build("built_in_test", test_config=0), "FB C1 29 00",
                 {"test_config": 0}, 76,
                 "AA 0B 00 00 4C 05 00 FB C1 29 00 02 41",  # 0x5C+FB+C1+29+00 = 0x0241
                 id="0xFB-built_in_test-off"),
]


@pytest.mark.parametrize(("build", "data_hex", "arguments", "node", "packet_hex"),
                         COMMAND_VECTORS)
def test_command_bytes_and_packet(build, data_hex, arguments, node, packet_hex):
    """Host to node: the builder's bytes, its ASPP packet, and parse() giving it back."""
    data, packet = _hex(data_hex), _hex(packet_hex)
    # the hand-written vector itself must hold together
    assert _command_packet(node, data) == packet
    assert packet[5] == len(data) + 1
    assert int.from_bytes(packet[-2:], "big") == _sum16(packet[1:-2])

    command = build()
    assert command.data == data
    assert command.code == data[0]
    assert dict(command.arguments) == arguments
    assert command.expects_reply is (data[0] != 0xFA)
    assert command.packet(node) == packet
    assert encode_command_packet(node, data) == packet
    assert decode_command_packet(packet) == (node, data)

    parsed = commands.parse(data)
    assert parsed == command
    assert parsed.data == data


def test_command_packet_with_a_wrong_checksum_is_refused():
    """The reference's NACK example: C2 to node 76 with an incorrect checksum."""
    good = _hex("AA 0B 00 00 4C 02 00 C2 01 1B")
    assert decode_command_packet(good) == (76, b"\xC2")
    with pytest.raises(PacketError):
        decode_command_packet(_hex("AA 0B 00 00 4C 02 00 C2 01 1C"))


# --- 2. node to host: every reply record inside a reply packet -------------------------

ACCEL = (0.5, -1.0, 1.5)
ANG_RATE = (0.25, -0.125, 2.0)
MAG = (0.375, -0.5, 0.625)
DELTA_ANGLE = (0.001953125, -0.5, 0.75)
DELTA_VELOCITY = (-2.0, 4.0, 0.0625)
M = ((1.0, 0.0, 0.0), (0.0, 0.5, -0.5), (0.25, -0.25, -1.0))
C = ((1.0, -0.0078125, 0.015625), (0.0078125, 1.0, -0.03125), (-0.015625, 0.03125, 1.0))


def _rows(matrix) -> tuple[float, ...]:
    """Row major, as the reference lists M and C: M11, M12, M13, M21, ..., M33."""
    return tuple(v for row in matrix for v in row)


REPLY_VECTORS = [
    # record bytes, its length per the reference (response bytes minus the 2-byte
    # checksum), record name, fields, node, LQI, RSSI byte, RSSI dBm
    pytest.param(
        _rec(0xC1, _f32(32768.0, 16384.5, 65535.0), _f32(100.25, 0.0, 50000.0),
             _u32(0x12345678)), 29,
        "raw_sensors", {"raw_accel": (32768.0, 16384.5, 65535.0),
                        "raw_ang_rate": (100.25, 0.0, 50000.0), "timer": 0x12345678},
        76, 0xFF, 0xD4, -44, id="0xC1-raw_sensors"),
    pytest.param(
        _rec(0xC2, _f32(*ACCEL), _f32(*ANG_RATE), _u32(0x00ABCDEF)), 29,
        "accel_angrate", {"accel": ACCEL, "ang_rate": ANG_RATE, "timer": 0x00ABCDEF},
        76, 0x80, 0x7F, 127, id="0xC2-accel_angrate"),
    pytest.param(
        _rec(0xC3, _f32(*DELTA_ANGLE), _f32(*DELTA_VELOCITY), _u32(0xFFFFFFFF)), 29,
        "delta_angle_velocity", {"delta_angle": DELTA_ANGLE,
                                 "delta_velocity": DELTA_VELOCITY, "timer": 0xFFFFFFFF},
        0x1234, 0x00, 0x80, -128, id="0xC3-delta_angle_velocity"),
    pytest.param(
        _hex("C4 C2 80 00 00 00"), 6,
        "continuous_mode", {"continuous_command": 0xC2, "timer": 0x80000000},
        76, 0xFF, 0xD4, -44, id="0xC4-continuous_mode"),
    pytest.param(
        _hex("C4 00 00 00 00 05"), 6,
        "continuous_mode", {"continuous_command": 0, "timer": 5},
        76, 0x20, 0xB0, -80, id="0xC4-continuous_mode-stopped"),
    pytest.param(
        _rec(0xC5, _f32(*_rows(M)), _u32(1)), 41,
        "orientation", {"orientation": M, "timer": 1},
        76, 0x5A, 0x00, 0, id="0xC5-orientation"),
    pytest.param(
        _rec(0xC6, _f32(*_rows(C)), _u32(19_660_800)), 41,
        "orientation_update", {"orientation_update": C, "timer": 19_660_800},
        76, 0x33, 0xC8, -56, id="0xC6-orientation_update"),
    pytest.param(
        _rec(0xC7, _f32(*MAG), _u32(0x0000FFFF)), 17,
        "mag", {"mag": MAG, "timer": 0x0000FFFF},
        76, 0xFF, 0xD4, -44, id="0xC7-mag"),
    pytest.param(
        _rec(0xC8, _f32(*ACCEL), _f32(*ANG_RATE), _f32(*_rows(M)), _u32(0x01020304)), 65,
        "accel_angrate_orientation", {"accel": ACCEL, "ang_rate": ANG_RATE,
                                      "orientation": M, "timer": 0x01020304},
        0xFFFE, 0x9B, 0xD4, -44, id="0xC8-accel_angrate_orientation"),
    pytest.param(
        _rec(0xC9, _f32(0.5, -1.0, 2.0), _u32(0x00001000)), 17,
        "accel_bias", {"accel_bias": (0.5, -1.0, 2.0), "timer": 0x00001000},
        76, 0x9B, 0xD4, -44, id="0xC9-accel_bias"),
    pytest.param(
        _rec(0xCA, _f32(0.25, 0.0, -0.125), _u32(0x00002000)), 17,
        "gyro_bias", {"gyro_bias": (0.25, 0.0, -0.125), "timer": 0x00002000},
        76, 0x9B, 0xD4, -44, id="0xCA-gyro_bias"),
    pytest.param(
        _rec(0xCB, _f32(*ACCEL), _f32(*ANG_RATE), _f32(*MAG), _u32(0x7FFFFFFF)), 41,
        "accel_angrate_mag", {"accel": ACCEL, "ang_rate": ANG_RATE, "mag": MAG,
                              "timer": 0x7FFFFFFF},
        76, 0x9B, 0xD4, -44, id="0xCB-accel_angrate_mag"),
    pytest.param(
        _rec(0xCC, _f32(*ACCEL), _f32(*ANG_RATE), _f32(*MAG), _f32(*_rows(M)),
             _u32(0x00C0FFEE)), 77,
        "accel_angrate_mag_orientation", {"accel": ACCEL, "ang_rate": ANG_RATE, "mag": MAG,
                                          "orientation": M, "timer": 0x00C0FFEE},
        76, 0x9B, 0xD4, -44, id="0xCC-accel_angrate_mag_orientation"),
    pytest.param(
        _rec(0xCD, _f32(0.0009765625, -0.001953125, 0.00048828125), _u32(0x0BADF00D)), 17,
        "capture_gyro_bias", {"gyro_bias": (0.0009765625, -0.001953125, 0.00048828125),
                              "timer": 0x0BADF00D},
        76, 0x9B, 0xD4, -44, id="0xCD-capture_gyro_bias"),
    pytest.param(
        _rec(0xCE, _f32(0.5), _f32(-0.25), _f32(3.0), _u32(100)), 17,
        "euler", {"roll": 0.5, "pitch": -0.25, "yaw": 3.0, "timer": 100},
        76, 0x9B, 0xD4, -44, id="0xCE-euler"),
    pytest.param(
        _rec(0xCF, _f32(-1.5), _f32(0.125), _f32(-3.0), _f32(*ANG_RATE), _u32(200)), 29,
        "euler_angrate", {"roll": -1.5, "pitch": 0.125, "yaw": -3.0,
                          "ang_rate": ANG_RATE, "timer": 200},
        76, 0x9B, 0xD4, -44, id="0xCF-euler_angrate"),
    pytest.param(
        _hex("D0 00 02 00 12 D6 87"), 7,
        "store_nonvolatile", {"quantity": 2, "timer": 0x0012D687},
        0x1234, 0x80, 0x7F, 127, id="0xD0-store_nonvolatile"),
    pytest.param(
        _hex("D0 FF FF 00 00 00 01"), 7,  # 0xFFFF: the quantity was not valid
        "store_nonvolatile", {"quantity": 0xFFFF, "timer": 1},
        76, 0x9B, 0xD4, -44, id="0xD0-store_nonvolatile-refused"),
    pytest.param(
        _hex("D1 0A 1B 08 00 0F FF 80 01 00 01 00 00"), 13,
        "temperatures", {"temperature": (0x0A1B, 0x0800, 0x0FFF, 0x8001),
                         "timer": 0x00010000},
        76, 0x00, 0x80, -128, id="0xD1-temperatures"),
    pytest.param(
        _rec(0xD2, _f32(0.0, 0.0, -1.0), _f32(*ANG_RATE), _f32(*MAG), _u32(42)), 41,
        "stab_accel_angrate_mag", {"stab_accel": (0.0, 0.0, -1.0), "ang_rate": ANG_RATE,
                                   "stab_mag": MAG, "timer": 42},
        76, 0x9B, 0xD4, -44, id="0xD2-stab_accel_angrate_mag"),
    pytest.param(
        _rec(0xD3, _f32(*DELTA_ANGLE), _f32(*DELTA_VELOCITY), _f32(*MAG), _u32(43)), 41,
        "delta_angle_velocity_mag", {"delta_angle": DELTA_ANGLE,
                                     "delta_velocity": DELTA_VELOCITY, "mag": MAG,
                                     "timer": 43},
        0x1234, 0x9B, 0xD4, -44, id="0xD3-delta_angle_velocity_mag"),
    pytest.param(
        _hex("E4 02 00"), 3,
        "eeprom_write", {"value": 512},
        76, 0x5A, 0x00, 0, id="0xE4-eeprom_write"),
    pytest.param(
        _hex("E5 80 C2"), 3,
        "eeprom_read", {"value": 0x80C2},
        0xFFFE, 0x33, 0xC8, -56, id="0xE5-eeprom_read"),
    pytest.param(
        _hex("E9 00 00 08 40"), 5,
        "firmware_version", {"version": 2112},
        76, 0x9B, 0xD4, -44, id="0xE9-firmware_version"),
    pytest.param(
        _hex("E9 80 00 00 01"), 5,  # all 32 bits are the number: unsigned
        "firmware_version", {"version": 0x80000001},
        76, 0x9B, 0xD4, -44, id="0xE9-firmware_version-top-bit"),
    pytest.param(
        # "4200-1076" then 7 spaces: 34 32 30 30 2D 31 30 37 36 20*7
        _hex("EA 01 34 32 30 30 2D 31 30 37 36 20 20 20 20 20 20 20"), 18,
        "device_id", {"selector": 1, "text": "4200-1076"},
        76, 0x9B, 0xD4, -44, id="0xEA-device_id-serial"),
    pytest.param(
        # "Inertia Link" (inner space kept) then 4 spaces
        _rec(0xEA, b"\x02", b"Inertia Link    "), 18,
        "device_id", {"selector": 2, "text": "Inertia Link"},
        76, 0x9B, 0xD4, -44, id="0xEA-device_id-name"),
    pytest.param(
        _hex("FB 14"), 2,  # erratum: the reference says 8 bytes; its fields total 4
        "built_in_test", {"test_config": 0x14},
        76, 0x9B, 0xD4, -44, id="0xFB-built_in_test"),
]


@pytest.mark.parametrize(
    ("record", "size", "name", "fields", "node", "lqi", "rssi_byte", "rssi"),
    REPLY_VECTORS)
def test_reply_record_in_packet(record, size, name, fields, node, lqi, rssi_byte, rssi):
    """Node to host: a hand-built reply packet decodes to one Reply and the contract's
    record; encode() reproduces the hand-built record."""
    assert len(record) == size
    packet = _reply_packet(node, record, lqi, rssi_byte)
    assert packet[5] == size + 1

    decoder = Decoder()
    events = decoder.feed(packet)
    assert events == [Reply(packet)]
    (reply,) = events
    assert reply.node == node
    assert reply.command == record[0]
    assert reply.payload == record
    assert reply.lqi == lqi
    assert reply.rssi == rssi
    assert decoder.line_idle() == []

    decoded = records.decode(reply.payload)
    assert decoded.name == name
    assert decoded.command == record[0]
    assert list(decoded.as_dict()) == list(fields)
    assert _plain(decoded.as_dict()) == _plain(fields)
    assert decoded.timer == fields.get("timer")

    assert records.lookup(name).code == record[0]
    assert records.lookup(record[0]).name == name
    assert records.encode(name, **fields) == record
    assert records.encode(record[0], **fields) == record


# Small records written out whole, with the reply checksum worked by hand.
REPLY_PACKET_VECTORS = [
    # 07+00+00+4C+07+00 = 0x5A; + C4+C2+80 = 0x260 (FF D4 not summed)
    pytest.param(76, "C4 C2 80 00 00 00", 0xFF, 0xD4,
                 "AA 07 00 00 4C 07 00 C4 C2 80 00 00 00 FF D4 02 60", id="0xC4"),
    # 07+00+12+34+08+00 = 0x55; + D0+02+12+D6+87 = 0x296
    pytest.param(0x1234, "D0 00 02 00 12 D6 87", 0x80, 0x7F,
                 "AA 07 00 12 34 08 00 D0 00 02 00 12 D6 87 80 7F 02 96", id="0xD0"),
    # 0x61 + D1+0A+1B+08+0F+FF+80+01+01 = 0x2EF
    pytest.param(76, "D1 0A 1B 08 00 0F FF 80 01 00 01 00 00", 0x00, 0x80,
                 "AA 07 00 00 4C 0E 00 D1 0A 1B 08 00 0F FF 80 01 00 01 00 00 00 80 02 EF",
                 id="0xD1"),
    # 0x57 + E4+02+00 = 0x13D
    pytest.param(76, "E4 02 00", 0x5A, 0x00,
                 "AA 07 00 00 4C 04 00 E4 02 00 5A 00 01 3D", id="0xE4"),
    # 07+00+FF+FE+04+00 = 0x208; + E5+80+C2 = 0x42F
    pytest.param(0xFFFE, "E5 80 C2", 0x33, 0xC8,
                 "AA 07 00 FF FE 04 00 E5 80 C2 33 C8 04 2F", id="0xE5"),
    # 0x59 + E9+08+40 = 0x18A
    pytest.param(76, "E9 00 00 08 40", 0x9B, 0xD4,
                 "AA 07 00 00 4C 06 00 E9 00 00 08 40 9B D4 01 8A", id="0xE9"),
    # 0x66 + EA+01 + 34+32+30+30+2D+31+30+37+36 (0x1C1) + 7*20 (0xE0) = 0x3F2
    pytest.param(76, "EA 01 34 32 30 30 2D 31 30 37 36 20 20 20 20 20 20 20", 0x9B, 0xD4,
                 "AA 07 00 00 4C 13 00 EA 01 34 32 30 30 2D 31 30 37 36"
                 " 20 20 20 20 20 20 20 9B D4 03 F2", id="0xEA"),
    # 0x56 + FB+14 = 0x165
    pytest.param(76, "FB 14", 0x9B, 0xD4,
                 "AA 07 00 00 4C 03 00 FB 14 9B D4 01 65", id="0xFB"),
]


@pytest.mark.parametrize(("node", "record_hex", "lqi", "rssi_byte", "packet_hex"),
                         REPLY_PACKET_VECTORS)
def test_reply_packet_literal(node, record_hex, lqi, rssi_byte, packet_hex):
    """Whole reply packets written by hand: the local helper and aspp agree with them."""
    packet, record = _hex(packet_hex), _hex(record_hex)
    assert _reply_packet(node, record, lqi, rssi_byte) == packet
    rssi = rssi_byte - 256 if rssi_byte > 127 else rssi_byte
    assert encode_reply_packet(node, record, lqi, rssi) == packet
    assert Decoder().feed(packet) == [Reply(packet)]


def test_device_id_text_strips_trailing_nuls():
    """0xEA padded with NULs: the text comes back without them (contract section 2)."""
    # "3DM-GX2" = 33 44 4D 2D 47 58 32, then 9 NULs
    record = _hex("EA 02 33 44 4D 2D 47 58 32 00 00 00 00 00 00 00 00 00")
    assert len(record) == 18
    # 0x66 + EA+02 + 33+44+4D+2D+47+58+32 = 0x314
    packet = _hex("AA 07 00 00 4C 13 00 EA 02 33 44 4D 2D 47 58 32"
                  " 00 00 00 00 00 00 00 00 00 9B D4 03 14")
    assert _reply_packet(76, record, 0x9B, 0xD4) == packet
    (reply,) = Decoder().feed(packet)
    decoded = records.decode(reply.payload)
    assert decoded.name == "device_id"
    assert decoded.as_dict() == {"selector": 2, "text": "3DM-GX2"}


def test_stop_continuous_has_no_reply_record():
    """0xFA is never answered: no record decodes from it and none can be encoded."""
    assert records.lookup(0xFA).name == "stop_continuous"
    assert commands.stop_continuous().expects_reply is False
    with pytest.raises(RecordError):
        records.decode(b"\xFA")


# --- 3. the reference's wireless example, erratum fixed --------------------------------

# C2 record: accel (1/128, -1/64, -1), ang_rate (1/512, 0, -1/1024), timer 0x0012D687
EXAMPLE_RECORD = _hex("C2 3C 00 00 00 BC 80 00 00 BF 80 00 00"
                      " 3B 00 00 00 00 00 00 00 BA 80 00 00 00 12 D6 87")
# 07+00+00+4C+1E+00 = 0x71; + record (0x65D) = 0x6CE; LQI 9B, RSSI D4 not summed
EXAMPLE_REPLY = _hex("AA 07 00 00 4C 1E 00 C2 3C 00 00 00 BC 80 00 00 BF 80 00 00"
                     " 3B 00 00 00 00 00 00 00 BA 80 00 00 00 12 D6 87 9B D4 06 CE")
EXAMPLE_STREAM = b"\xAA" + EXAMPLE_REPLY  # the base station's ACK, then the reply


def _check_example(events):
    assert events == [Ack(), Reply(EXAMPLE_REPLY)]
    reply = events[1]
    assert reply.node == 76
    assert reply.command == 0xC2  # the reference prints 0xC1 here: the echo is 0xC2
    assert reply.payload == EXAMPLE_RECORD
    assert reply.lqi == 0x9B
    assert reply.rssi == -44
    decoded = records.decode(reply.payload)
    assert decoded.name == "accel_angrate"
    assert _plain(decoded.as_dict()) == _plain({
        "accel": (0.0078125, -0.015625, -1.0),
        "ang_rate": (0.001953125, 0.0, -0.0009765625),
        "timer": 0x0012D687})


def test_example_request_packet():
    """PC sends AA 0B 00 <addr> 2 0 C2 <ck>: for node 76, 0x59 + C2 = 0x011B."""
    packet = _hex("AA 0B 00 00 4C 02 00 C2 01 1B")
    assert commands.poll(0xC2).packet(76) == packet


def test_example_reply_vector_is_consistent():
    """The example's hand-written reply: length byte 30, 28 data bytes after the echo."""
    assert EXAMPLE_STREAM[:3] == _hex("AA AA 07")
    assert EXAMPLE_REPLY[5] == 30
    assert len(EXAMPLE_RECORD) == 1 + 28
    assert EXAMPLE_RECORD == _rec(0xC2, _f32(0.0078125, -0.015625, -1.0),
                                  _f32(0.001953125, 0.0, -0.0009765625), _u32(0x0012D687))
    assert _reply_packet(76, EXAMPLE_RECORD, 0x9B, 0xD4) == EXAMPLE_REPLY


def test_example_ack_then_reply_fed_whole():
    """AA AA 07 ...: the ACK, then the reply, from one read."""
    decoder = Decoder()
    events = decoder.feed(EXAMPLE_STREAM)
    events += decoder.line_idle()
    _check_example(events)


def test_example_ack_then_reply_fed_byte_by_byte():
    """The same stream one byte per read gives the same events."""
    decoder = Decoder()
    events = []
    for i in range(len(EXAMPLE_STREAM)):
        events += decoder.feed(EXAMPLE_STREAM[i:i + 1])
    events += decoder.line_idle()
    _check_example(events)


def test_example_nack():
    """The rejected request: the base station answers 0x21, a lone byte: known as one
    when the next packet starts or the line goes quiet."""
    decoder = Decoder()
    assert decoder.feed(b"\x21") == []
    assert decoder.line_idle() == [Nack()]
    assert Decoder().feed(b"\x21\xaa") == [Nack()]


# --- 4. the raw wireless ping ---------------------------------------------------------

@pytest.mark.parametrize(("node", "expected"), [
    pytest.param(76, "02 00 4C", id="node-76"),
    pytest.param(0x1234, "02 12 34", id="node-0x1234"),
    pytest.param(65534, "02 FF FE", id="node-65534"),
    pytest.param(1, "02 00 01", id="node-1"),
])
def test_raw_ping_bytes(node, expected):
    """02 <addr MSB> <addr LSB>, never wrapped in a packet."""
    assert encode_ping(node) == _hex(expected)
    assert encode_ping(node) == _hex(expected)


@pytest.mark.parametrize(("answer", "event"), [
    pytest.param(b"\x02", PingOk(), id="0x02-node-answered"),
    pytest.param(b"\x21", Nack(), id="0x21-no-answer"),
])
def test_raw_ping_answer(answer, event):
    """The base station's one-byte answer to a ping, alone on a quiet line."""
    decoder = Decoder()
    assert decoder.feed(answer) == []
    assert decoder.line_idle() == [event]


# --- 5. the 0xFB erratum, and records of the wrong length -----------------------------

def test_built_in_test_reply_is_two_bytes():
    """0xFB's record is the echo plus TestConfig: 2 bytes (length byte 3), not 8."""
    packet = _hex("AA 07 00 00 4C 03 00 FB 30 9B D4 01 81")  # 0x56 + FB + 30 = 0x181
    assert _reply_packet(76, _hex("FB 30"), 0x9B, 0xD4) == packet
    (reply,) = Decoder().feed(packet)
    assert reply.payload == _hex("FB 30")
    decoded = records.decode(reply.payload)
    assert decoded.name == "built_in_test"
    assert decoded.as_dict() == {"test_config": 0x30}


ACCEL_ANGRATE = _rec(0xC2, _f32(*ACCEL), _f32(*ANG_RATE), _u32(7))

WRONG_LENGTH = [
    pytest.param(ACCEL_ANGRATE[:-1], id="0xC2-one-byte-short"),
    pytest.param(ACCEL_ANGRATE + b"\x00", id="0xC2-one-byte-long"),
    pytest.param(_hex("C2"), id="0xC2-echo-only"),
    pytest.param(_hex("C4 C2 00 00 00"), id="0xC4-short"),
    pytest.param(_rec(0xC5, _f32(*_rows(M))), id="0xC5-no-timer"),
    pytest.param(_hex("D1 0A 1B 08 00 0F FF 80 01 00 01 00"), id="0xD1-short"),
    pytest.param(_hex("E5 80"), id="0xE5-short"),
    pytest.param(_hex("E9 00 00 08"), id="0xE9-short"),
    pytest.param(_hex("EA 01 34 32 30 30"), id="0xEA-short"),
    pytest.param(_hex("FB"), id="0xFB-echo-only"),
    pytest.param(b"", id="empty"),
    pytest.param(_hex("02 00 4C"), id="0x02-not-a-record"),
    pytest.param(_hex("FA"), id="0xFA-no-reply"),
]


@pytest.mark.parametrize("record", WRONG_LENGTH)
def test_record_that_does_not_fit_its_layout_raises(record):
    """A record is never decoded from the wrong number of bytes or an unknown echo."""
    with pytest.raises(RecordError):
        records.decode(record)


# --- 6. NaN magnetometer (Inertia-Link) ------------------------------------------------

# 7FC00000 is the quiet NaN; FFC00000 and 7F800001 are NaNs too.
NAN_VECTORS = [
    pytest.param(_hex("C7 7F C0 00 00 7F C0 00 00 7F C0 00 00 00 00 12 34"),
                 "mag", ("mag",), 0x1234, id="0xC7-quiet-nan"),
    pytest.param(_hex("C7 FF C0 00 00 7F 80 00 01 7F FF FF FF 00 00 12 35"),
                 "mag", ("mag",), 0x1235, id="0xC7-other-nans"),
    pytest.param(_rec(0xCB, _f32(*ACCEL), _f32(*ANG_RATE), _hex("7F C0 00 00") * 3,
                      _u32(0x1236)),
                 "accel_angrate_mag", ("mag",), 0x1236, id="0xCB-inertia-link"),
    pytest.param(_rec(0xD3, _f32(*DELTA_ANGLE), _f32(*DELTA_VELOCITY),
                      _hex("7F C0 00 00") * 3, _u32(0x1237)),
                 "delta_angle_velocity_mag", ("mag",), 0x1237, id="0xD3-inertia-link"),
]


@pytest.mark.parametrize(("record", "name", "nan_fields", "timer"), NAN_VECTORS)
def test_nan_magnetometer_decodes_to_nan(record, name, nan_fields, timer):
    """An Inertia-Link's magnetometer is NaN; NaN is a value, not an error."""
    packet = _reply_packet(76, record, 0x9B, 0xD4)
    (reply,) = Decoder().feed(packet)
    decoded = records.decode(reply.payload)
    assert decoded.name == name
    assert decoded.timer == timer
    for field_name, value in decoded.as_dict().items():
        if field_name in nan_fields:
            assert len(value) == 3
            assert all(math.isnan(v) for v in value)
        elif field_name != "timer":
            assert not any(math.isnan(v) for v in value)


def test_nan_magnetometer_encodes_as_quiet_nan():
    """encode() of NaNs gives the quiet NaN 7FC00000 the hand-built record carries."""
    nan = float("nan")
    assert records.encode("mag", mag=(nan, nan, nan), timer=0x1234) == _hex(
        "C7 7F C0 00 00 7F C0 00 00 7F C0 00 00 00 00 12 34")


# --- 7. checksum vectors, including 16-bit rollover ------------------------------------

@pytest.mark.parametrize(("data", "expected"), [
    pytest.param(_hex("0B 00 00 4C 02 00 C2"), 0x011B, id="example-command"),
    pytest.param(b"\xFF" * 257, 0xFFFF, id="257xFF-just-no-wrap"),  # 257*FF = 0xFFFF
    pytest.param(b"\xFF" * 257 + b"\x01", 0x0000, id="wrap-to-zero"),  # 0xFFFF + 1
    pytest.param(b"\xFF" * 258, 0x00FE, id="258xFF-wraps"),  # 258*FF = 0x100FE -> 0x00FE
    pytest.param(b"\xFF" * 300, 0x2AD4, id="300xFF-wraps"),  # 300*FF = 0x12AD4
])
def test_checksum_vectors(data, expected):
    """The 16-bit sum rolls over from 65535 to 0."""
    assert _sum16(data) == expected
    assert checksum(data) == expected


# The largest GX2 record (0xCC, 77 bytes) of 0xFF data: 07+00+FF+FE+4E+00 = 0x252,
# + CC = 0x31E, + 76 * FF (0x4BB4) = 0x4ED2. A GX2 record is too short to wrap the sum.
CC_ALL_FF = b"\xCC" + b"\xFF" * 76
CC_ALL_FF_PACKET = _hex("AA 07 00 FF FE 4E 00") + CC_ALL_FF + _hex("10 B0 4E D2")

# No valid GX2 command or reply packet can wrap the sum: the reference caps the data at
# 100 bytes. A packet at the largest length byte the header allows (255: 254 bytes after
# the unused byte), all 0xFF, from node 0xFFFE does: 07+00+FF+FE+FF+00 = 0x303,
# + 254 * FF (0xFD02) = 0x10005, which wraps to 0x0005. Its length is beyond a reply's,
# so the decoder may class it as a Frame; what matters is that its checksum holds.
WRAP_PAYLOAD = b"\xFF" * 254
WRAP_PACKET = _hex("AA 07 00 FF FE FF 00") + WRAP_PAYLOAD + _hex("FF FF 00 05")


def test_largest_record_of_ff_data():
    """0xCC full of 0xFF bytes: every float NaN, timer 0xFFFFFFFF, checksum 0x4ED2."""
    assert _reply_packet(0xFFFE, CC_ALL_FF, 0x10, 0xB0) == CC_ALL_FF_PACKET
    assert encode_reply_packet(0xFFFE, CC_ALL_FF, 0x10, -80) == CC_ALL_FF_PACKET
    (reply,) = Decoder().feed(CC_ALL_FF_PACKET)
    assert reply == Reply(CC_ALL_FF_PACKET)
    assert (reply.node, reply.lqi, reply.rssi) == (0xFFFE, 0x10, -80)
    decoded = records.decode(reply.payload)
    assert decoded.name == "accel_angrate_mag_orientation"
    assert decoded.timer == 0xFFFFFFFF
    values = decoded.as_dict()
    floats = [*values["accel"], *values["ang_rate"], *values["mag"],
              *_rows(values["orientation"])]
    assert len(floats) == 18
    assert all(math.isnan(v) for v in floats)


def test_reply_packet_checksum_wraps():
    """A packet whose sum passes 0xFFFF carries the sum mod 65536 and is a valid packet."""
    assert _reply_packet(0xFFFE, WRAP_PAYLOAD, 0xFF, 0xFF) == WRAP_PACKET
    assert encode_reply_packet(0xFFFE, WRAP_PAYLOAD, 0xFF, -1) == WRAP_PACKET
    decoder = Decoder()
    events = decoder.feed(WRAP_PACKET) + decoder.line_idle()
    assert events in ([Reply(WRAP_PACKET)], [Frame(WRAP_PACKET)])


@pytest.mark.parametrize("wrong", [
    pytest.param(_hex("00 06"), id="one-too-many"),
    pytest.param(_hex("00 04"), id="one-too-few"),
    pytest.param(_hex("FF FF"), id="all-ones"),
])
def test_reply_packet_with_wrong_wrapped_checksum_is_not_a_reply(wrong):
    """The same packet with a wrong checksum is not a packet at all."""
    packet = WRAP_PACKET[:-2] + wrong
    decoder = Decoder()
    events = decoder.feed(packet) + decoder.line_idle()
    assert events
    assert not any(isinstance(e, (Reply, Frame)) for e in events)
