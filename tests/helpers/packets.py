"""Packet builders for tests: reply packets as a base station sends them, and packets
with any header bytes at all (which the library's own builder refuses to make)."""

from __future__ import annotations

from aspp.frame import SOP, checksum, encode_reply_packet


def pkt(payload: bytes, node: int = 76, lqi: int = 0x64, rssi: int = -44,
        flags: int = 0x07) -> bytes:
    """A reply packet (or, with other flags, a frame) from ``node``."""
    return encode_reply_packet(node, payload, lqi=lqi, rssi=rssi, flags=flags)


def raw_packet(flags: int, node: int, payload: bytes, app: int = 0, unused: int = 0,
               lqi: int = 0, rssi_byte: int = 0) -> bytes:
    """A checksum-valid packet with any header bytes (encode_reply_packet refuses some:
    node 0, flags 0xAA, a nonzero unused byte)."""
    body = bytes((flags, app, node >> 8, node & 0xFF, len(payload) + 1, unused)) + payload
    return bytes((SOP,)) + body + bytes((lqi, rssi_byte)) + checksum(body).to_bytes(2, "big")
