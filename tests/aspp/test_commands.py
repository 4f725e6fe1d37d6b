"""Command builders: every bad argument raises one CommandError naming it, before any
byte exists; good arguments give the bytes the reference defines."""

from __future__ import annotations

import math

import pytest

from aspp import commands
from aspp.errors import AsppError, CommandError, PacketError
from aspp.frame import decode_command_packet, encode_command_packet, encode_ping
from aspp.records import STREAMABLE, all_specs, lookup
from aspp.timing import divider_for_rate

BAD_ARGUMENTS = [
    ("node 0", lambda: commands.poll("euler").packet(0), PacketError, "node address 0"),
    ("node 65535", lambda: commands.poll("euler").packet(65535), PacketError, "65535"),
    ("node bool", lambda: encode_ping(True), PacketError, "node address"),
    ("node float", lambda: encode_ping(76.0), PacketError, "node address"),
    ("eeprom address", lambda: commands.read_eeprom(0x10000), CommandError, "address"),
    ("eeprom negative", lambda: commands.read_eeprom(-1), CommandError, "address"),
    ("eeprom value", lambda: commands.write_eeprom(0xFCA2, 70000), CommandError, "value"),
    ("eeprom value str", lambda: commands.write_eeprom(0xFCA2, "512"), CommandError, "value"),
    ("eeprom value fraction", lambda: commands.write_eeprom(1, 2.5), CommandError, "value"),
    ("divider low", lambda: commands.set_divider(169), CommandError, "divider 169"),
    ("divider high", lambda: commands.set_divider(51201), CommandError, "divider 51201"),
    ("rate too fast", lambda: divider_for_rate(400), CommandError, "400"),
    ("rate zero", lambda: divider_for_rate(0), CommandError, "rate"),
    ("selector", lambda: commands.device_id(4), CommandError, "selector 4"),
    ("sampling time 0", lambda: commands.capture_gyro_bias(0), CommandError, "sampling_time"),
    ("sampling time big", lambda: commands.capture_gyro_bias(70000), CommandError,
     "sampling_time"),
    ("quantity", lambda: commands.store_nonvolatile(3), CommandError, "quantity 3"),
    ("test config", lambda: commands.built_in_test(256), CommandError, "test_config"),
    ("bias length", lambda: commands.write_accel_bias((1.0, 2.0)), CommandError, "accel_bias"),
    ("bias nan", lambda: commands.write_gyro_bias((0.0, math.nan, 0.0)), CommandError,
     "gyro_bias[1]"),
    ("bias text", lambda: commands.write_gyro_bias("abc"), CommandError, "gyro_bias"),
    ("stream a command", lambda: commands.set_continuous("eeprom_read"), CommandError,
     "eeprom_read"),
    ("stream unknown", lambda: commands.set_continuous("nope"), CommandError, "nope"),
    ("poll with args", lambda: commands.poll("device_id"), CommandError, "device_id"),
    ("poll stop", lambda: commands.poll(0xFA), CommandError, "stop_continuous"),
    ("unknown byte", lambda: commands.build(0x42), CommandError, "0x42"),
    ("missing arg", lambda: commands.build("eeprom_read"), CommandError, "address"),
    ("extra arg", lambda: commands.build("euler", speed=3), CommandError, "speed"),
    ("continuous cmd", lambda: commands.build(0xC4, continuous_command=0xE5), CommandError,
     "continuous_command"),
    ("empty packet", lambda: encode_command_packet(76, b""), PacketError, "1..100"),
    ("long packet", lambda: encode_command_packet(76, b"\xc2" * 101), PacketError, "1..100"),
]


@pytest.mark.parametrize(("build", "error", "names"), [c[1:] for c in BAD_ARGUMENTS],
                         ids=[c[0] for c in BAD_ARGUMENTS])
def test_bad_argument_raises_one_clear_error(build, error, names):
    with pytest.raises(error) as caught:
        build()
    assert names in str(caught.value)
    assert "\n" not in str(caught.value)
    assert isinstance(caught.value, AsppError)


def test_data_rate_divider_round_trip():
    assert divider_for_rate(100) == 512
    assert divider_for_rate(1) == 51200
    assert commands.set_divider(512).data == bytes.fromhex("E4 C1 29 00 FC A2 02 00")
    assert commands.set_divider(170).arguments == {"address": 0xFCA2, "value": 170}


def test_auto_start_marks_the_word_wireless():
    assert commands.set_auto_start("accel_angrate").arguments["value"] == 0x80C2
    assert commands.set_auto_start(None).arguments["value"] == 0
    with pytest.raises(CommandError):
        commands.set_auto_start("firmware_version")


def test_every_streamable_record_builds_a_continuous_command():
    for code in STREAMABLE:
        command = commands.set_continuous(code)
        assert command.data == bytes((0xC4, 0xC1, 0x29, code))
        assert commands.parse(command.data) == command


def test_every_pollable_record_is_one_byte():
    for spec in all_specs():
        if spec.pollable:
            assert commands.poll(spec.name).data == bytes((spec.code,))


def test_only_stop_continuous_expects_no_reply():
    silent = [s.name for s in all_specs() if not commands.build(s.code, **_args(s))
              .expects_reply]
    assert silent == ["stop_continuous"]


def _args(spec):
    sample = {"continuous_command": 0xC2, "accel_bias": (0, 0, 0), "gyro_bias": (0, 0, 0),
              "sampling_time": 10000, "quantity": 1, "address": 0xFCA2, "value": 1,
              "selector": 0, "test_config": 0}
    return {f.name: sample[f.name] for f in spec.arguments}


PARSE_REJECTS = [
    ("empty", b"", "no command byte"),
    ("unknown", b"\x42", "0x42"),
    ("short", b"\xc4\xc1\x29", "takes 4 bytes"),
    ("long", b"\xc2\x00", "takes 1 bytes"),
    ("confirm", b"\xc4\xc1\x28\xc2", "confirmation bytes"),
    ("eeprom confirm", bytes.fromhex("E4 C1 29 01 FC A2 02 00"), "confirmation"),
    ("selector", b"\xea\x07", "selector 7"),
    ("stream non-record", b"\xc4\xc1\x29\xe9", "continuous_command"),
]


@pytest.mark.parametrize(("data", "names"), [c[1:] for c in PARSE_REJECTS],
                         ids=[c[0] for c in PARSE_REJECTS])
def test_device_side_parse_rejects_what_a_node_would_ignore(data, names):
    with pytest.raises(CommandError, match=names):
        commands.parse(data)


def test_command_packet_validation_on_the_base_station_side():
    packet = commands.read_eeprom(0xFCA2).packet(76)
    assert decode_command_packet(packet) == (76, bytes.fromhex("E5 00 FC A2"))
    corrupt = [
        packet[:-1] + bytes([packet[-1] ^ 1]),       # checksum
        b"\xab" + packet[1:],                         # SOP
        packet[:1] + b"\x07" + packet[2:],            # flags
        packet[:5] + bytes([packet[5] + 1]) + packet[6:],  # length byte
        packet[:-3] + packet[-2:],                    # a byte missing
    ]
    for bad in corrupt:
        with pytest.raises(PacketError):
            decode_command_packet(bad)


def test_lookup_by_name_byte_and_hex_text():
    assert lookup("euler").code == 0xCE
    assert lookup(0xCE).name == "euler"
    assert lookup("0xce").name == "euler"
    assert lookup(" 0xCE ").name == "euler"
    for bad in ("0xZZ", "Euler", "", 0x42, 3.0, None):
        with pytest.raises(AsppError):
            lookup(bad)
