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

import struct
import zlib
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
_HEADER = struct.Struct(">HBHBB")
"""SOP and delivery flags together, app data type, node, length, the unused byte."""
_REPLY_START = (SOP << 8) | FLAGS_REPLY
_REPLY_SIZE = tuple(length + _SIZE_FROM_LENGTH if 2 <= length <= _MAX_REPLY_LENGTH else 0
                    for length in range(256))
"""A reply packet's size by its length byte; 0 where no reply has that length."""
# a Reply built without NamedTuple's Python-level __new__: 1.6x cheaper (0.38 against
# 0.59 us, bench/micro.py), about a tenth of the decoder's time per packet
_new_tuple = tuple.__new__


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
        self._buf = b""
        """What is held between calls; bytes, so a packet is cut out with one copy."""
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
        if type(data) is not bytes:
            data = bytes(data)  # (a copy: later changes to a mutable input don't count)
        self._buf = self._buf + data if self._buf else data
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
        unpack_header = _HEADER.unpack_from
        adler32 = zlib.adler32
        reply_size, reply_start, new_tuple = _REPLY_SIZE, _REPLY_START, _new_tuple
        replies = 0
        run_goes_on = self._run_goes_on
        last_header = n - HEADER_SIZE
        while pos < n:
            if pos <= last_header:
                # the common case first, in as few steps as Python allows: a whole reply
                # whose checksum holds. Its sum is below 65521 (at most 107 bytes of
                # 255), so Adler-32's low half is exactly 1 + the sum, computed in C
                # rather than a byte at a time (1.9x the checksum of sum(),
                # bench/micro.py; the fast path as a whole made the decoder 1.9x
                # faster with 4 KiB reads, bench/decoder_throughput.py)
                start_flags, app, node, length, unused = unpack_header(buf, pos)
                end = pos + reply_size[length]
                if (start_flags == reply_start and not app and not unused
                        and 0 < node < 0xFFFF and pos < end):
                    if end > n:
                        if not final:
                            break  # a reply the read cut short: wait for the rest
                    elif adler32(buf[pos + 1:end - 4]) & 0xFFFF == (
                            (buf[end - 2] << 8) | buf[end - 1]) + 1:
                        append(new_tuple(Reply, (buf[pos:end],)))
                        replies += 1
                        run_goes_on = False
                        pos = end
                        continue
            byte = buf[pos]
            if byte == SOP:
                run_goes_on = False
                if pos + 1 < n and buf[pos + 1] == SOP:  # no packet has flags 0xAA
                    append(ACK_EVENT)
                    stats.acks += 1
                    pos += 1
                    continue
                if pos > last_header and not final:
                    break  # a header the read cut short
                candidate = self._failed_candidate(pos, n, final)
                if candidate is None:
                    break
                if type(candidate) is not DiscardReason:  # an ACK, a Frame or a Reply
                    append(candidate)
                    pos += 1 if candidate is ACK_EVENT else len(candidate[0])
                    continue
                end = self._run_end(pos, n, final)
                if end is None:
                    break
                append(self._discard(pos, end, candidate))  # never a lone byte: see AA AA
                run_goes_on = end - pos == MAX_DISCARD
                pos = end
            else:
                end = self._run_end(pos, n, final)
                if end is None:
                    break
                alone = end - pos == 1 and not run_goes_on
                if alone and byte == NACK:
                    append(NACK_EVENT)
                    stats.nacks += 1
                elif alone and byte == PING:
                    append(PING_OK_EVENT)
                    stats.ping_oks += 1
                else:
                    append(self._discard(pos, end, DiscardReason.GARBAGE))
                run_goes_on = end - pos == MAX_DISCARD
                pos = end
        self._run_goes_on = run_goes_on
        stats.replies += replies
        self._buf = buf[pos:] if pos else buf
        return out

    def _failed_candidate(self, pos: int, n: int,
                          final: bool) -> Event | DiscardReason | None:
        """The 0xAA at ``pos`` did not start a whole reply with a good checksum (the fast
        path) nor an ACK before another 0xAA: what it is instead. An event (an ACK at
        the end of the line, a Frame, or a Reply after all), the reason the bytes from
        ``pos`` are discarded, or None if that waits for more bytes."""
        buf = self._buf
        avail = n - pos
        if avail < HEADER_SIZE:
            if not final:
                return None
            if avail == 1:
                self.stats.acks += 1
                return ACK_EVENT
            return DiscardReason.TRUNCATED
        length = buf[pos + 5]
        size = length + _SIZE_FROM_LENGTH
        node = (buf[pos + 3] << 8) | buf[pos + 4]
        trusted = (buf[pos + 1] == FLAGS_REPLY and buf[pos + 2] == APP_DATA_TYPE
                   and buf[pos + 6] == 0 and 2 <= length <= _MAX_REPLY_LENGTH
                   and 0 < node < 0xFFFF)
        if avail < size:
            if not (final or (not trusted and self._frame_within(pos + 1, n))):
                return None
            return DiscardReason.TRUNCATED
        if not trusted and self._frame_within(pos + 1, pos + size - 1):
            return DiscardReason.TRUNCATED
        ck = pos + size - 2
        if (sum(buf[pos + 1:ck - 2]) & 0xFFFF) != ((buf[ck] << 8) | buf[ck + 1]):
            return DiscardReason.BAD_CHECKSUM
        if not 0 < node < 0xFFFF:
            return DiscardReason.BAD_ADDRESS
        raw = buf[pos:pos + size]
        if trusted:
            self.stats.replies += 1
            return Reply(raw)
        self.stats.frames += 1
        return Frame(raw)

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
        return _new_tuple(Discarded, (self._buf[start:end], reason))
