"""The base station's side of the serial line: the host's bytes -> command packets,
raw pings and malformed input (which a base station answers with a NACK).

The host sends one command at a time and waits for its ACK or NACK, so this side is
simpler than :mod:`aspp.decoder`: a packet's claimed length is trusted, and a packet
that fails validation is consumed whole. Sans-IO like the rest of :mod:`aspp`.
"""

from __future__ import annotations

from typing import NamedTuple

from .errors import PacketError
from .frame import COMMAND_OVERHEAD, HEADER_SIZE, PING, SOP, decode_command_packet


class CommandPacket(NamedTuple):
    """A well-formed command packet: deliver ``command`` to ``node`` and ACK it."""

    node: int
    command: bytes


class PingRequest(NamedTuple):
    """``02 MSB LSB``: ask whether ``node`` answers over the radio."""

    node: int


class Garbled(NamedTuple):
    """Bytes that are not a valid packet or ping; ``reason`` says why. A base station
    answers each with one NACK."""

    data: bytes
    reason: str


HostEvent = CommandPacket | PingRequest | Garbled


class HostStreamDecoder:
    """Feeds on what the host writes; yields :data:`HostEvent` in order."""

    __slots__ = ("_buf",)

    def __init__(self) -> None:
        self._buf = bytearray()

    def feed(self, data: bytes | bytearray | memoryview) -> list[HostEvent]:
        self._buf += data
        return self._decode(final=False)

    def line_idle(self) -> list[HostEvent]:
        """The host stopped mid-packet: what is buffered is malformed (truncated)."""
        return self._decode(final=True)

    def _decode(self, final: bool) -> list[HostEvent]:
        buf = self._buf
        out: list[HostEvent] = []
        pos = 0
        n = len(buf)
        while pos < n:
            byte = buf[pos]
            if byte == PING:
                if n - pos < 3:
                    break
                out.append(PingRequest((buf[pos + 1] << 8) | buf[pos + 2]))
                pos += 3
            elif byte == SOP:
                if n - pos < HEADER_SIZE:
                    break
                size = buf[pos + 5] + COMMAND_OVERHEAD - 1
                if size < COMMAND_OVERHEAD + 1:
                    size = HEADER_SIZE  # no command byte: refuse the header alone
                    out.append(Garbled(bytes(buf[pos:pos + size]), "no command byte"))
                    pos += size
                    continue
                if n - pos < size:
                    break
                packet = bytes(buf[pos:pos + size])
                try:
                    out.append(CommandPacket(*decode_command_packet(packet)))
                except PacketError as error:
                    out.append(Garbled(packet, str(error)))
                pos += size
            else:
                end = pos + 1
                while end < n and buf[end] not in (SOP, PING):
                    end += 1
                if end == n and not final:
                    break  # the run may go on in the next write: one NACK per run
                out.append(Garbled(bytes(buf[pos:end]), f"bad SOP 0x{byte:02X}"))
                pos = end
        if final and pos < n:
            out.append(Garbled(bytes(buf[pos:n]), "truncated"))
            pos = n
        del buf[:pos]
        return out
