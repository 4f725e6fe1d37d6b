"""The streaming decoder for bytes from the base station: ``feed(bytes)`` -> events.

It is sans-IO: no port, no clock. The caller feeds whatever it read and gets back
events (:mod:`aspp.events`); when the line has gone quiet it calls :meth:`line_idle`
so that what waits for more bytes (a trailing 0xAA, a cut-off packet) is resolved.

How the bytes are read, in order of the stream:

* An 0xAA is a packet candidate; its header gives the packet's length. A packet is
  valid when its checksum holds and its node address is 1..65534.
* A candidate whose header is a plausible reply header (flags 0x07, app type 0x00,
  unused byte 0x00, length at most 102, a valid node) is decided by its checksum
  alone: a truncated reply delays what follows it by at most one packet length.
  Any other candidate (an 0xAA inside data followed by a bogus length) gives way to a
  valid packet that starts inside it and completes first, without waiting for the
  bytes it claims.
* A failed candidate is discarded up to the next 0xAA. So an ACK is only recognised
  as the byte before another 0xAA, or alone when the line goes idle: a caller that
  sent a command with no reply (0xFA) calls :meth:`line_idle` when the line is quiet.
* ACK and SOP are the same byte. An 0xAA followed by another 0xAA is an ACK at once
  (no packet has delivery flags 0xAA). A trailing 0xAA waits for the next byte, or for
  :meth:`line_idle`, which makes it an ACK.
* Between packets, a lone 0x21 is a NACK and a lone 0x02 a positive ping answer: the
  base station sends them as single bytes between packets. Inside a longer run of
  bytes that are not packets they are garbage like the rest of the run, so random
  noise cannot answer a command or a ping. Whether a byte stands alone is known from
  the next byte (or :meth:`line_idle`).

Every decision depends only on the bytes, never on how they were split into chunks,
so feeding a stream whole, halved or byte by byte gives exactly the same events. What
it holds between calls is bounded: an unfinished packet (at most 265 bytes) or an
unfinished run of discarded bytes (at most ``MAX_DISCARD`` bytes).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .events import (
    ACK_EVENT,
    NACK_EVENT,
    PING_OK_EVENT,
    Discarded,
    DiscardReason,
    Event,
    Frame,
    Reply,
)
from .frame import (
    APP_DATA_TYPE,
    FLAGS_REPLY,
    HEADER_SIZE,
    MAX_COMMAND_BYTES,
    NACK,
    PING,
    REPLY_OVERHEAD,
    SOP,
)

MAX_DISCARD = 512
"""Longest run reported in one :class:`Discarded`; a longer run comes in pieces."""

_MIN_FRAME = REPLY_OVERHEAD - 1  # a packet whose length byte is 0
_MAX_REPLY_LENGTH = MAX_COMMAND_BYTES + 2  # the unused byte, the echo, 100 data bytes
_SIZE_FROM_LENGTH = REPLY_OVERHEAD - 1
_SOP_BYTE = bytes((SOP,))


@dataclass
class DecoderStats:
    """Running totals: what came out of the stream and what was dropped, and why."""

    replies: int = 0
    frames: int = 0
    acks: int = 0
    nacks: int = 0
    ping_oks: int = 0
    discarded_bytes: dict[DiscardReason, int] = field(
        default_factory=lambda: dict.fromkeys(DiscardReason, 0))
    discarded_runs: dict[DiscardReason, int] = field(
        default_factory=lambda: dict.fromkeys(DiscardReason, 0))

    @property
    def packets(self) -> int:
        return self.replies + self.frames

    @property
    def bytes_discarded(self) -> int:
        return sum(self.discarded_bytes.values())


class Decoder:
    """Turns the byte stream from a base station into :mod:`aspp.events`."""

    __slots__ = ("_buf", "_run_goes_on", "stats")

    def __init__(self) -> None:
        self._buf = bytearray()
        self._run_goes_on = False
        """The last discarded piece was cut at MAX_DISCARD: what follows it, up to the
        next 0xAA, belongs to the same run, so a single byte there is not alone."""
        self.stats = DecoderStats()

    @property
    def pending(self) -> int:
        """Bytes held back until more arrive or the line goes idle."""
        return len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview) -> list[Event]:
        """Add bytes read from the line; return every event they complete."""
        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise TypeError(f"feed() takes bytes, not {type(data).__name__}")
        self._buf += data
        return self._decode(final=False)

    def line_idle(self) -> list[Event]:
        """The line has gone quiet: resolve everything still waiting for bytes.

        A trailing 0xAA becomes an ACK; an unfinished packet is discarded as truncated.
        """
        return self._decode(final=True)

    def _decode(self, final: bool) -> list[Event]:
        buf = self._buf
        n = len(buf)
        pos = 0
        out: list[Event] = []
        append = out.append
        stats = self.stats
        while pos < n:
            byte = buf[pos]
            if byte == SOP:
                self._run_goes_on = False
                avail = n - pos
                if avail >= 2 and buf[pos + 1] == SOP:
                    append(ACK_EVENT)
                    stats.acks += 1
                    pos += 1
                    continue
                if avail < HEADER_SIZE:
                    if not final:
                        break
                    if avail == 1:
                        append(ACK_EVENT)
                        stats.acks += 1
                        pos += 1
                        continue
                    reason = DiscardReason.TRUNCATED
                else:
                    length = buf[pos + 5]
                    size = length + _SIZE_FROM_LENGTH
                    node = (buf[pos + 3] << 8) | buf[pos + 4]
                    trusted = (buf[pos + 1] == FLAGS_REPLY and buf[pos + 2] == APP_DATA_TYPE
                               and buf[pos + 6] == 0 and 2 <= length <= _MAX_REPLY_LENGTH
                               and 0 < node < 0xFFFF)
                    if avail < size:
                        if not (final or (not trusted and self._frame_within(pos + 1, n))):
                            break
                        reason = DiscardReason.TRUNCATED
                    elif not trusted and self._frame_within(pos + 1, pos + size - 1):
                        reason = DiscardReason.TRUNCATED
                    else:
                        ck = pos + size - 2
                        if (sum(buf[pos + 1:ck - 2]) & 0xFFFF) != ((buf[ck] << 8) | buf[ck + 1]):
                            reason = DiscardReason.BAD_CHECKSUM
                        elif not 0 < node < 0xFFFF:
                            reason = DiscardReason.BAD_ADDRESS
                        else:
                            raw = bytes(buf[pos:pos + size])
                            if trusted:
                                append(Reply(raw))
                                stats.replies += 1
                            else:
                                append(Frame(raw))
                                stats.frames += 1
                            pos += size
                            continue
                end = self._run_end(pos, n, final)
                if end is None:
                    break
                append(self._discard(pos, end, reason))  # never a lone byte: see AA AA
                self._run_goes_on = end - pos == MAX_DISCARD
                pos = end
            else:
                end = self._run_end(pos, n, final)
                if end is None:
                    break
                alone = end - pos == 1 and not self._run_goes_on
                if alone and byte == NACK:
                    append(NACK_EVENT)
                    stats.nacks += 1
                elif alone and byte == PING:
                    append(PING_OK_EVENT)
                    stats.ping_oks += 1
                else:
                    append(self._discard(pos, end, DiscardReason.GARBAGE))
                self._run_goes_on = end - pos == MAX_DISCARD
                pos = end
        if pos:
            del buf[:pos]
        return out

    def _frame_within(self, start: int, limit: int) -> bool:
        """Is there a valid packet starting at or after ``start`` and ending by ``limit``?"""
        last_start = limit - _MIN_FRAME + 1  # exclusive; never negative: find() would
        if last_start <= start:             # read a negative bound from the end
            return False
        buf = self._buf
        j = buf.find(_SOP_BYTE, start, last_start)
        while j != -1:
            if buf[j + 1] != SOP and 0 < ((buf[j + 3] << 8) | buf[j + 4]) < 0xFFFF:
                end = j + buf[j + 5] + _SIZE_FROM_LENGTH
                if end <= limit and (sum(buf[j + 1:end - 4]) & 0xFFFF) == (
                        (buf[end - 2] << 8) | buf[end - 1]):
                    return True
            j = buf.find(_SOP_BYTE, j + 1, last_start)
        return False

    def _run_end(self, pos: int, n: int, final: bool) -> int | None:
        """Where a run of bytes outside packets that starts at ``pos`` ends: at the next
        0xAA (the next possible packet), or None if that is not known yet. A run is cut
        at MAX_DISCARD bytes, so the decoder never holds more than that.
        """
        limit = min(n, pos + MAX_DISCARD)
        end = self._buf.find(_SOP_BYTE, pos + 1, limit)
        if end != -1:
            return end
        if limit == pos + MAX_DISCARD or final:
            return limit
        return None

    def _discard(self, start: int, end: int, reason: DiscardReason) -> Discarded:
        self.stats.discarded_bytes[reason] += end - start
        self.stats.discarded_runs[reason] += 1
        return Discarded(bytes(self._buf[start:end]), reason)
