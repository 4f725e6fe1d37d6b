"""What the stream decoder yields: small immutable events, one per thing on the line.

Events are NamedTuples rather than frozen dataclasses for one measured reason: the
decoder builds one per packet at up to several hundred thousand per second, and a
frozen dataclass costs about 2 us to construct against about 0.4 us for a tuple.
:func:`type_strict` makes their equality strict, so an ``Ack()`` never equals a
``Nack()`` and a ``Reply`` never equals a ``Frame`` holding the same bytes.

A packet event keeps only its raw bytes; every field is read from them on demand, so
an event is exactly as trustworthy as the bytes it was decoded from.
"""

from __future__ import annotations

import struct
from enum import StrEnum
from typing import NamedTuple, TypeVar

from .frame import HEADER_SIZE

LINK_QUALITY = struct.Struct(">Bb")
"""LQI and RSSI (dBm, signed), the two bytes before a packet's checksum."""


T = TypeVar("T", bound=type)


def type_strict(cls: T) -> T:
    """A NamedTuple equal only to an instance of its own class (a plain tuple compares
    by value alone, so ``Ack() == Nack() == ()``), hashed with its class's name."""
    def __eq__(self: tuple, other: object) -> bool:
        return type(self) is type(other) and tuple.__eq__(self, other)  # type: ignore[arg-type]

    def __ne__(self: tuple, other: object) -> bool:
        return not __eq__(self, other)

    def __hash__(self: tuple) -> int:
        return hash((type(self).__name__, tuple(self)))

    cls.__eq__, cls.__ne__, cls.__hash__ = __eq__, __ne__, __hash__  # type: ignore[method-assign,assignment]
    return cls


@type_strict
class Reply(NamedTuple):
    """A valid reply packet carrying a GX2 reply record: delivery flags 0x07, app type
    0x00, the unused byte 0x00 and a length of 2..102 (an echo byte and at most 100
    data bytes), from node 1..65534.

    ``payload`` is the wired reply record without its own checksum: the echo byte
    first, then the data, ready for :func:`aspp.records.decode`.
    """

    raw: bytes

    @property
    def node(self) -> int:
        return (self.raw[3] << 8) | self.raw[4]

    @property
    def command(self) -> int:
        """The echo byte, which always equals the command that asked for the record."""
        return self.raw[HEADER_SIZE]

    @property
    def payload(self) -> bytes:
        return self.raw[HEADER_SIZE:-4]

    @property
    def lqi(self) -> int:
        return self.raw[-4]

    @property
    def rssi(self) -> int:
        """Received signal strength in dBm (a signed byte)."""
        return LINK_QUALITY.unpack_from(self.raw, len(self.raw) - 4)[1]  # type: ignore[no-any-return]


@type_strict
class Frame(NamedTuple):
    """A valid packet that is not a reply: other delivery flags (0x00 is a node's
    power-up discovery packet), or a header that is not a reply's (no echo byte, more
    than 100 data bytes, a nonzero app type or unused byte)."""

    raw: bytes

    @property
    def flags(self) -> int:
        return self.raw[1]

    @property
    def app_data_type(self) -> int:
        return self.raw[2]

    @property
    def node(self) -> int:
        return (self.raw[3] << 8) | self.raw[4]

    @property
    def payload(self) -> bytes:
        """The bytes after the header's unused byte, before LQI and RSSI."""
        return self.raw[HEADER_SIZE:-4]

    @property
    def lqi(self) -> int:
        return self.raw[-4]

    @property
    def rssi(self) -> int:
        return LINK_QUALITY.unpack_from(self.raw, len(self.raw) - 4)[1]  # type: ignore[no-any-return]

    @property
    def is_discovery(self) -> bool:
        return self.raw[1] == 0x00


@type_strict
class Ack(NamedTuple):
    """0xAA outside any packet: the base station accepted and broadcast a command."""


@type_strict
class Nack(NamedTuple):
    """0x21 outside any packet: the base station refused a malformed command packet,
    or, after a raw ping, reports that the node did not answer."""


@type_strict
class PingOk(NamedTuple):
    """0x02 outside any packet: the pinged node answered over the radio."""


class DiscardReason(StrEnum):
    GARBAGE = "garbage"
    """Bytes that could not start a packet nor be an ACK, NACK or ping answer."""
    BAD_CHECKSUM = "bad_checksum"
    """A complete packet whose checksum did not match."""
    BAD_ADDRESS = "bad_address"
    """A packet whose checksum holds but whose node address is 0 or 0xFFFF: no node
    has those, and a run of zero bytes inside data looks exactly like such a packet."""
    TRUNCATED = "truncated"
    """A header that is not a plausible reply's, given way to a valid packet that
    starts inside it and completes first (a false header: 0xAA inside data followed by
    a bogus length), or any unfinished packet when the line goes quiet. A cut-off reply
    whose header is plausible waits for the bytes it claims and then fails its
    checksum, so it is counted as ``bad_checksum``."""


@type_strict
class Discarded(NamedTuple):
    """Bytes the decoder dropped, and why. Every byte fed is accounted for exactly
    once: in a packet, as a control byte, in a ``Discarded``, or still buffered."""

    data: bytes
    reason: DiscardReason


ACK_EVENT = Ack()
NACK_EVENT = Nack()
PING_OK_EVENT = PingOk()

Event = Reply | Frame | Ack | Nack | PingOk | Discarded
_CONTROL_BYTES = {Ack: b"\xaa", Nack: b"\x21", PingOk: b"\x02"}


def stream_bytes(event: Event) -> bytes:
    """The bytes of the stream that ``event`` stands for: the packet, the control byte
    or the discarded run. Joined in order, they give back every byte fed to the decoder
    (for capture and replay, or for logging exactly what was dropped)."""
    if isinstance(event, (Reply, Frame)):
        return event.raw
    if isinstance(event, Discarded):
        return event.data
    return _CONTROL_BYTES[type(event)]
