"""Helpers both decoder test files use: run a stream through a decoder, the bytes events
stand for, and the stats a list of events should have produced."""

from __future__ import annotations

from collections.abc import Iterable

from aspp.decoder import Decoder, DecoderStats
from aspp.events import Ack, Event, Frame, Nack, PingOk, Reply, stream_bytes


def decode_chunks(chunks: Iterable[bytes]) -> tuple[list[Event], Decoder]:
    """Feed every chunk, then line_idle(); the events and the decoder."""
    decoder = Decoder()
    events: list[Event] = []
    for chunk in chunks:
        events += decoder.feed(chunk)
    events += decoder.line_idle()
    return events, decoder


def represented(events: Iterable[Event]) -> bytes:
    """The bytes the events stand for, in order."""
    return b"".join(stream_bytes(event) for event in events)


def stats_for(events: Iterable[Event]) -> DecoderStats:
    """The DecoderStats that producing ``events`` should leave behind."""
    expected = DecoderStats()
    for event in events:
        if isinstance(event, Reply):
            expected.replies += 1
        elif isinstance(event, Frame):
            expected.frames += 1
        elif isinstance(event, Ack):
            expected.acks += 1
        elif isinstance(event, Nack):
            expected.nacks += 1
        elif isinstance(event, PingOk):
            expected.ping_oks += 1
        else:
            expected.discarded_bytes[event.reason] += len(event.data)
            expected.discarded_runs[event.reason] += 1
    return expected
