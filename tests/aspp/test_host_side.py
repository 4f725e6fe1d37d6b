"""The base station's side of the line (what the simulator's base station parses):
command packets, raw pings and malformed input, however the host's writes are split."""

from __future__ import annotations

import pytest

from aspp import commands
from aspp.frame import encode_ping
from aspp.host_side import CommandPacket, Garbled, HostStreamDecoder, PingRequest

POLL = commands.poll("euler").packet(76)
WRITE = commands.write_eeprom(0xFCA2, 512).packet(0x1234)
BAD_CK = POLL[:-1] + bytes([POLL[-1] ^ 0x01])

CASES = [
    ("packet", POLL, [CommandPacket(76, b"\xce")]),
    ("ping then packet", encode_ping(77) + WRITE,
     [PingRequest(77), CommandPacket(0x1234, commands.write_eeprom(0xFCA2, 512).data)]),
    ("bad checksum consumed whole", BAD_CK + POLL,
     [Garbled(BAD_CK, "checksum 0x0126 does not match the sum 0x0127"),
      CommandPacket(76, b"\xce")]),
    ("junk is one NACK per run", b"\x13\x37" + POLL,
     [Garbled(b"\x13\x37", "bad SOP 0x13"), CommandPacket(76, b"\xce")]),
    ("header without a command", bytes.fromhex("AA 0B 00 00 4C 01 00") + POLL,
     [Garbled(bytes.fromhex("AA 0B 00 00 4C 01 00"), "no command byte"),
      CommandPacket(76, b"\xce")]),
]


@pytest.mark.parametrize(("data", "expected"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
@pytest.mark.parametrize("split", ["whole", "bytes"])
def test_host_stream(data, expected, split):
    decoder = HostStreamDecoder()
    if split == "whole":
        events = decoder.feed(data)
    else:
        events = [e for i in range(len(data)) for e in decoder.feed(data[i:i + 1])]
    assert events + decoder.line_idle() == expected


def test_a_host_that_stops_mid_packet_gets_a_nack_on_idle():
    decoder = HostStreamDecoder()
    assert decoder.feed(POLL[:5]) == []
    assert decoder.line_idle() == [Garbled(POLL[:5], "truncated")]
    assert decoder.feed(POLL) == [CommandPacket(76, b"\xce")]


def test_a_device_parses_structure_and_leaves_meaning_to_the_firmware():
    odd_quantity = bytes.fromhex("D0 C1 29 00 07")
    with pytest.raises(commands.CommandError):
        commands.parse(odd_quantity)
    assert commands.parse(odd_quantity, check_arguments=False).arguments["quantity"] == 7
    with pytest.raises(commands.CommandError, match="confirmation"):
        commands.parse(bytes.fromhex("D0 C1 28 00 01"), check_arguments=False)
