"""ASPP packet framing: constants, the checksum, and packet encode/validate.

The Agile-Link Serial Packet Protocol wraps each GX2 command and reply for the radio.
Both directions share one header; only replies from the base station carry LQI and RSSI:

    command (host -> base):  AA 0B 00 <addr:2> <len> 00 <n command bytes>        <ck:2>
    reply   (base -> host):  AA 07 00 <addr:2> <len> 00 <m reply bytes> LQI RSSI <ck:2>

``len`` counts the unused 0x00 byte plus the command or reply bytes (n+1, m+1). The
checksum is the 16-bit sum of every byte after the SOP up to the last command or reply
byte: never the SOP, LQI or RSSI.
"""

from __future__ import annotations

import struct
from typing import Final

from .errors import PacketError

SOP: Final = 0xAA
"""Start of packet. The base station's ACK has the same value."""
ACK: Final = 0xAA
NACK: Final = 0x21
"""Refusal of a malformed packet, and also the base station's "node did not answer"
to a raw ping: the same byte, told apart only by what the host last sent."""
PING: Final = 0x02
"""The raw wireless ping command byte, and the base station's positive answer to it."""

FLAGS_COMMAND: Final = 0x0B
FLAGS_REPLY: Final = 0x07
FLAGS_DISCOVERY: Final = 0x00
APP_DATA_TYPE: Final = 0x00

HEADER_SIZE: Final = 7
"""SOP, flags, app data type, address (2), length, the unused byte."""
CHECKSUM_SIZE: Final = 2
LINK_QUALITY_SIZE: Final = 2
"""LQI and RSSI, present only in packets from the base station."""
COMMAND_OVERHEAD: Final = HEADER_SIZE + CHECKSUM_SIZE
REPLY_OVERHEAD: Final = HEADER_SIZE + LINK_QUALITY_SIZE + CHECKSUM_SIZE

MIN_NODE: Final = 1
MAX_NODE: Final = 65534
MAX_COMMAND_BYTES: Final = 100

_HEADER = struct.Struct(">BBBHBB")
_CHECKSUM = struct.Struct(">H")


def checksum(data: bytes | bytearray | memoryview) -> int:
    """The 16-bit sum, mod 65536, that ASPP and the wired GX2 protocol both use."""
    return sum(data) & 0xFFFF


def check_node(node: int) -> int:
    """Return ``node`` if it is a usable node address (1..65534), else raise."""
    if isinstance(node, bool) or not isinstance(node, int):
        raise PacketError(f"node address must be an integer, not {node!r}")
    if not MIN_NODE <= node <= MAX_NODE:
        raise PacketError(f"node address {node} is out of range {MIN_NODE}..{MAX_NODE}")
    return node


def encode_command_packet(node: int, command: bytes) -> bytes:
    """Wrap ``command`` (1..100 GX2 command bytes) for delivery to ``node``."""
    check_node(node)
    if not 1 <= len(command) <= MAX_COMMAND_BYTES:
        raise PacketError(
            f"command must be 1..{MAX_COMMAND_BYTES} bytes, not {len(command)}")
    body = _HEADER.pack(SOP, FLAGS_COMMAND, APP_DATA_TYPE, node, len(command) + 1, 0)
    body += command
    return body + _CHECKSUM.pack(checksum(memoryview(body)[1:]))


def encode_reply_packet(node: int, reply: bytes, lqi: int = 0, rssi: int = 0,
                        flags: int = FLAGS_REPLY) -> bytes:
    """Build a packet as the base station sends it: ``reply`` is the wired record
    without its own checksum (echo byte first). Used by the simulator and in tests."""
    check_node(node)
    if not 0 <= len(reply) <= 254:
        raise PacketError(f"reply must be 0..254 bytes, not {len(reply)}")
    if not 0 <= lqi <= 255:
        raise PacketError(f"lqi {lqi} is out of range 0..255")
    if not -128 <= rssi <= 127:
        raise PacketError(f"rssi {rssi} dBm is out of range -128..127")
    if not 0 <= flags <= 255 or flags == SOP:
        raise PacketError(f"delivery flags 0x{flags:02X} cannot be sent")
    body = _HEADER.pack(SOP, flags, APP_DATA_TYPE, node, len(reply) + 1, 0) + reply
    return (body + bytes((lqi, rssi & 0xFF))
            + _CHECKSUM.pack(checksum(memoryview(body)[1:])))


def encode_ping(node: int) -> bytes:
    """The raw wireless ping: ``02 <addr MSB> <addr LSB>``, never wrapped in a packet."""
    check_node(node)
    return bytes((PING, node >> 8, node & 0xFF))


def decode_command_packet(packet: bytes) -> tuple[int, bytes]:
    """Validate one whole command packet; return ``(node, command bytes)``.

    This is the base station's side of the link (the simulator uses it): anything that
    is not exactly one well-formed command packet raises :class:`PacketError`, which is
    what the base station answers with a NACK.
    """
    if len(packet) < COMMAND_OVERHEAD + 1:
        raise PacketError(f"packet of {len(packet)} bytes is too short")
    sop, flags, _app, node, length, _unused = _HEADER.unpack_from(packet)
    if sop != SOP:
        raise PacketError(f"bad SOP 0x{sop:02X}")
    if flags != FLAGS_COMMAND:
        raise PacketError(f"delivery flags 0x{flags:02X} are not a command's 0x0B")
    if len(packet) != length + COMMAND_OVERHEAD - 1:
        raise PacketError(f"length byte {length} does not match a {len(packet)}-byte packet")
    if not 2 <= length <= MAX_COMMAND_BYTES + 1:
        raise PacketError(f"length byte {length} is out of range 2..{MAX_COMMAND_BYTES + 1}")
    end = len(packet) - CHECKSUM_SIZE
    (want,) = _CHECKSUM.unpack_from(packet, end)
    got = checksum(memoryview(packet)[1:end])
    if got != want:
        raise PacketError(f"checksum 0x{want:04X} does not match the sum 0x{got:04X}")
    if node == 0 or node == 0xFFFF:
        raise PacketError(f"node address {node} is out of range {MIN_NODE}..{MAX_NODE}")
    return node, bytes(packet[HEADER_SIZE:end])


def reply_packet_size(length_byte: int) -> int:
    """Total size of a packet from the base station whose length byte is ``length_byte``."""
    return length_byte - 1 + REPLY_OVERHEAD
