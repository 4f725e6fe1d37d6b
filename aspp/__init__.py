"""aspp: the 3DM-GX2 wireless protocol (ASPP packets, GX2 commands and records), sans-IO.

Bytes in, events out; typed commands in, bytes out. Nothing here opens a port, reads a
clock or starts a thread: the gateway and the simulator do that at the edges.
"""

from .commands import Command
from .decoder import Decoder, DecoderStats
from .errors import AsppError, CommandError, PacketError, RecordError
from .events import (
    Ack,
    Discarded,
    DiscardReason,
    Event,
    Frame,
    Nack,
    PingOk,
    Reply,
    stream_bytes,
)
from .frame import ACK, NACK, PING, SOP, checksum, encode_command_packet, encode_ping
from .records import CommandSpec, Record, decode, encode, lookup
from .stop import GaveUp, SendStop, Stopped, StopPolicy, WaitUntil
from .timing import TICKS_PER_SECOND, TimerUnwrapper

__all__ = [
    "ACK", "NACK", "PING", "SOP", "TICKS_PER_SECOND",
    "Ack", "AsppError", "Command", "CommandError", "CommandSpec", "Decoder",
    "DecoderStats", "DiscardReason", "Discarded", "Event", "Frame", "GaveUp", "Nack",
    "PacketError", "PingOk", "Record", "RecordError", "Reply", "SendStop", "StopPolicy",
    "Stopped", "TimerUnwrapper", "WaitUntil", "checksum", "decode", "encode",
    "encode_command_packet", "encode_ping", "lookup", "stream_bytes",
]
