"""A chunk's messages at once: their channels and times as arrays, their data as a list,
in the order written. The reader hands a recording out so (:func:`.reader.read_blocks`),
a block a chunk; the export of tables takes it so, a window's and a table's messages
picked out of a block at C's cost (whole blocks kept by their bounds, numpy over their
arrays), where a Python object made and tested per message (an :class:`.entry.Entry`)
cost more than a third of reading's CPU (1.6x less CPU to read a million rows with
blocks, bench/exportformats.py --before, issue 44). The readers that take messages
one at a time (replay, plot, the client) take a block's :meth:`Block.entries`, so both
read through the one walk and its damage handling.

The arrays are the standard library's (:mod:`array`), not numpy's: the gateway reads
recordings without numpy (a replay; an export to CSV without the extras), and numpy
takes them as they are (``numpy.frombuffer``, no copy)."""

from __future__ import annotations

import struct
from array import array
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field, replace

from mcap.opcode import Opcode

from .entry import Entry
from .files import MESSAGE_HEAD, RECORD_HEAD
from .index import channel_of

Span = tuple[int, int]
"""A window of log_time: (first ns, ns after the last), end excluded."""

_MESSAGE = struct.Struct(RECORD_HEAD.format + MESSAGE_HEAD.format.lstrip("<"))
"""A message record's head: opcode, length, then its channel, sequence, log_time and
publish_time."""
_MESSAGE_OP, _CHANNEL_OP = int(Opcode.MESSAGE), int(Opcode.CHANNEL)
CHANNELS, TIMES = "H", "Q"
"""The arrays' types: a channel id (u16), a time (u64 ns)."""


@dataclass(frozen=True)
class Block:
    """Messages in the order written: a chunk's (those of it a read keeps), or one
    written outside chunks."""

    channel: array[int]
    """Each message's channel id, as the file numbers them."""
    log_time: array[int]
    """Each message's log_time and publish_time (ns)."""
    publish_time: array[int]
    data: list[bytes]
    topics: Mapping[int, str] = field(default_factory=dict)
    """The topic of each channel among ``channel``."""
    after_damage: bool = False
    """A stretch of the file was skipped unread just before its first message (and
    after the message before it): what the streams miss across it was recorded, then
    lost by the file."""

    def __len__(self) -> int:
        return len(self.data)

    def taken(self, at: list[int]) -> Block:
        """Its messages at the places ``at`` (ascending)."""
        if len(at) == len(self):
            return self
        channel, log_time, publish_time, data = (
            self.channel, self.log_time, self.publish_time, self.data)
        return replace(self, channel=array(CHANNELS, [channel[i] for i in at]),
                       log_time=array(TIMES, [log_time[i] for i in at]),
                       publish_time=array(TIMES, [publish_time[i] for i in at]),
                       data=[data[i] for i in at])

    def marked(self, damaged: bool) -> Block:
        """The block, said to follow a skipped stretch (or not)."""
        return self if damaged == self.after_damage else replace(self, after_damage=damaged)

    def on(self, keeps: Callable[[str], bool]) -> frozenset[int] | None:
        """Its channels whose topic ``keeps`` keeps; None: every one."""
        chosen = frozenset(channel for channel, topic in self.topics.items() if keeps(topic))
        return None if len(chosen) == len(self.topics) else chosen

    def kept(self, span: Span | None = None, channels: frozenset[int] | None = None
             ) -> Block:
        """Its messages logged in ``span`` on ``channels`` (None: any); a block wholly in
        or out is told by its bounds and channels, without a look at each message."""
        if not len(self):
            return self
        if channels is not None and channels.issuperset(self.channel):
            channels = None
        low, high = (0, 2**64) if span is None else span
        first, last = min(self.log_time), max(self.log_time)
        if last < low or first >= high or channels == frozenset():
            return self.taken([])
        if channels is None and low <= first and last < high:
            return self
        return self.taken([i for i, (channel, log_time) in enumerate(
            zip(self.channel, self.log_time, strict=True))
            if low <= log_time < high and (channels is None or channel in channels)])

    @property
    def bytes(self) -> int:
        """Its messages' data, in bytes."""
        return sum(map(len, self.data))

    def entries(self) -> Iterator[Entry]:
        """Its messages one at a time."""
        topics = self.topics
        damaged = self.after_damage
        for channel, log_time, publish_time, data in zip(
                self.channel, self.log_time, self.publish_time, self.data, strict=True):
            yield Entry(topics[channel], log_time, publish_time, data, damaged)
            damaged = False


def entries_of(blocks: Iterable[Block]) -> Iterator[Entry]:
    """The messages of ``blocks``, one at a time."""
    for block in blocks:
        yield from block.entries()


def blocks_of(entries: Iterable[Entry], size: int = 4096) -> Iterator[Block]:
    """Messages given one at a time as blocks of up to ``size`` (a block begins at each
    that follows a skipped stretch): for a caller that has entries, not a reader."""
    ids: dict[str, int] = {}
    waiting: list[Entry] = []
    for entry in entries:
        if waiting and (entry.after_damage or len(waiting) >= size):
            yield _block(waiting, ids)
            waiting = []
        waiting.append(entry)
    if waiting:
        yield _block(waiting, ids)


def _block(entries: list[Entry], ids: dict[str, int]) -> Block:
    channel = [ids.setdefault(entry.topic, len(ids)) for entry in entries]
    return Block(array(CHANNELS, channel), array(TIMES, [e.log_time for e in entries]),
                 array(TIMES, [e.publish_time for e in entries]), [e.data for e in entries],
                 {ids[e.topic]: e.topic for e in entries}, entries[0].after_damage)


def parsed(records: bytes) -> tuple[Block, dict[int, str]]:
    """The messages of a chunk's records (their topics not set: the walk knows every
    channel), and the channels the records define; struct.error (or UnicodeDecodeError)
    where their framing does not add up."""
    channels: dict[int, str] = {}
    found: list[int] = []
    logged: list[int] = []
    published: list[int] = []
    data: list[bytes] = []
    head, message = RECORD_HEAD.unpack_from, _MESSAGE.unpack_from
    at, end = 0, len(records)
    last = end - _MESSAGE.size
    while at < end:
        # every record's head read as a message's (a channel's, its first bytes unused):
        # one unpack a message, not two, 1.35x the loop's speed (360,000 messages)
        if at <= last:
            opcode, length, channel, _, log_time, publish_time = message(records, at)
        else:
            opcode, length = head(records, at)
            if opcode == _MESSAGE_OP:
                raise struct.error("a message's head runs past its chunk")
        after = at + RECORD_HEAD.size + length
        if after > end:
            raise struct.error("a record runs past its chunk")
        if opcode == _MESSAGE_OP:
            found.append(channel)
            logged.append(log_time)
            published.append(publish_time)
            data.append(records[at + _MESSAGE.size:after])
        elif opcode == _CHANNEL_OP:
            channel, topic = channel_of(records[at + RECORD_HEAD.size:after])
            channels[channel] = topic
        at = after
    return Block(array(CHANNELS, found), array(TIMES, logged), array(TIMES, published),
                 data), channels


def one(channel: int, log_time: int, publish_time: int, data: bytes) -> Block:
    """A message written outside chunks, as a block."""
    return Block(array(CHANNELS, [channel]), array(TIMES, [log_time]),
                 array(TIMES, [publish_time]), [data])
