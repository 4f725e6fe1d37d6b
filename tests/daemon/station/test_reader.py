"""The reader's judgement of a quiet line from the reads' own times: a packet a stalled
loop finds split across two reads is whole, and a line that really went quiet still
resolves what waited (as a replay judges it: no timer, the reads and their times)."""

from __future__ import annotations

import pytest

from aspp.events import DiscardReason
from aspp.frame import encode_reply_packet
from aspp.records import encode
from aspp.timing import TICKS_PER_CLOCK, byte_time
from gateway.daemon.station.reader import Reader
from tests.helpers.wired import RecordingPublisher, one_node_reader

IDLE = 0.03
BYTE = byte_time(115200)


def stream(count: int, first: int = 1) -> bytes:
    """``count`` records of node 76's 100 Hz accel_angrate stream, back to back."""
    return b"".join(encode_reply_packet(76, encode(
        "accel_angrate", accel=(0, 0, -1), ang_rate=(0, 0, 0),
        timer=sample * 512 * TICKS_PER_CLOCK), lqi=200, rssi=-50)
        for sample in range(first, first + count))


def reader() -> tuple[Reader, RecordingPublisher]:
    return one_node_reader(IDLE, byte_time=BYTE)


def timers(publisher: RecordingPublisher) -> list[int]:
    return [p["timer"] // (512 * TICKS_PER_CLOCK) for p in publisher.records(76)]


def test_a_packet_a_stalled_loop_finds_split_across_two_reads_is_whole() -> None:
    data = stream(60)
    cut = 30  # inside the first packet (40 bytes)
    # the loop stalled 200 ms; meanwhile the line streamed on (the bytes of the second
    # read took 206 ms of it): at no moment was it quiet
    assert (len(data) - cut) * BYTE > 0.2
    got, publisher = reader()
    got.on_data(data[:cut], 1000.0, 50.0)
    got.on_data(data[cut:], 1000.2, 50.2)
    assert timers(publisher) == list(range(1, 61))
    assert got.decoder.stats.discarded_bytes[DiscardReason.TRUNCATED] == 0


def test_a_line_that_went_quiet_resolves_the_packet_it_cut_short() -> None:
    cut_short = stream(1)[:30]  # the base station stopped in the middle of a packet
    after = stream(2, first=2)  # then, 100 ms later, two whole packets (7 ms of line)
    got, publisher = reader()
    got.on_data(cut_short, 1000.0, 50.0)
    got.on_data(after, 1000.1, 50.1)
    assert timers(publisher) == [2, 3]
    assert got.decoder.stats.discarded_bytes[DiscardReason.TRUNCATED] == 30


def packet(sample: int) -> bytes:
    return stream(1, first=sample)


def test_which_packets_waited_behind_another_is_judged_from_the_reads() -> None:
    """A packet that began on the line within 0.5 ms of the last packet's read waited
    behind it and shows its clock no floor; one later did not. The first packet after
    the port opened may have waited behind bytes no read held: it shows none either."""
    got, _ = reader()
    clock = got.nodes[76].clock
    size = len(packet(1)) * BYTE  # (3.5 ms)
    got.on_data(packet(1), 1000.0, 50.0)  # the first read: what came before is unknown
    assert not clock.floor_seen
    at = 50.0
    for sample in range(2, 150):  # each read 10 ms after the last: the line was free
        at += 0.01
        got.on_data(packet(sample), 1000.0 + at - 50.0, at)
    assert clock.floor_seen and clock.floor_age == 0.0
    # two packets in one read: the second began as the first ended
    at += 0.01
    got.on_data(packet(150) + packet(151), 1000.0 + at - 50.0, at)
    assert clock.floor_age == pytest.approx(0.01)  # (the read's first did not wait; its second did)
    at += 0.0001 + size  # one that began 0.1 ms after the last read: it waited
    got.on_data(packet(152), 1000.0 + at - 50.0, at)
    assert clock.floor_age == pytest.approx(0.02)
    got.line_opened()  # the port reopened
    at += 0.01
    got.on_data(packet(153), 1000.0 + at - 50.0, at)
    assert clock.floor_age == pytest.approx(0.03)


def test_bytes_that_framed_nothing_took_the_line_and_a_packet_after_them_waited() -> None:
    """A packet whose checksum failed (or a discovery frame) was on the line as much as
    a reply: a packet that began as it ended waited behind it. (Judged against the last
    good reply, it counted as free, and one bad checksum ahead of a waiting node let its
    floor count as seen.)"""
    got, _ = reader()
    clock = got.nodes[76].clock
    at = 50.0
    for sample in range(1, 150):  # free packets: the floor seen
        at += 0.01
        got.on_data(packet(sample), 1000.0 + at - 50.0, at)
    assert clock.floor_age == 0.0
    corrupt = bytearray(packet(150))
    corrupt[-1] ^= 0xFF  # (its checksum)
    at += 0.01
    got.on_data(bytes(corrupt), 1000.0 + at - 50.0, at)
    at += len(corrupt) * BYTE  # the next began as the bad one ended
    got.on_data(packet(151), 1000.0 + at - 50.0, at)
    assert got.decoder.stats.discarded_bytes[DiscardReason.BAD_CHECKSUM] == len(corrupt)
    assert clock.floor_age == pytest.approx(0.02)  # (it waited: no floor seen)
