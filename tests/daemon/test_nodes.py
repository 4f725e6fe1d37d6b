"""A node on its own (the end-to-end tests drive it through a real pty): when its
stream falls silent, what its timer says of its rate, its losses and its reboots."""

from __future__ import annotations

import time

from aspp.frame import encode_reply_packet
from aspp.records import decode, encode
from aspp.timing import TICKS_PER_CLOCK, TICKS_PER_SECOND
from gateway.daemon.config import NodeEntry
from gateway.daemon.nodes import SILENCE_MIN, STEPS_CHECKED, Node, State


def test_silent_at_is_the_watchers_deadline() -> None:
    node = Node(NodeEntry(address=76, stream="accel_angrate"))
    assert node.silent_at() is None  # nothing streams yet: nothing to watch
    node.streaming("accel_angrate")
    due = node.silent_at()
    assert due is not None and due - time.monotonic() <= node.silence_limit
    assert node.silence_limit >= SILENCE_MIN
    assert not node.fell_silent(due)  # at the deadline itself: not yet
    assert node.fell_silent(due + 0.001)
    assert (node.state, node.silences, node.silent_at()) == (State.SILENT, 1, None)
    assert not node.fell_silent(due + 10)  # counted once, not on every look


def test_polled_mode_is_not_watched() -> None:
    node = Node(NodeEntry(address=76))
    node.polled()
    assert node.state is State.POLLED and node.silent_at() is None


def stream_record(node: Node, timer: int, at: float) -> dict:
    raw = encode_reply_packet(node.address, encode("accel_angrate", accel=(0, 0, -1),
                                                   ang_rate=(0, 0, 0), timer=timer))
    return node.tally(raw, decode(raw, 7, len(raw) - 4), at, at)


def test_the_divider_follows_the_streams_own_timer() -> None:
    """Its EEPROM said 512, but the node runs at 1024 (a real node applies a new divider
    only after a power cycle): after STEPS_CHECKED steps the divider is corrected, and
    the steps stop counting as lost records."""
    node = Node(NodeEntry(address=76))
    node.streaming("accel_angrate", 512)
    step = 1024 * TICKS_PER_CLOCK
    for i in range(STEPS_CHECKED + 1):
        stream_record(node, i * step, 100.0 + i * 0.02)
    assert node.divider == 1024
    lost = node.lost_radio
    for i in range(STEPS_CHECKED + 1, 3 * STEPS_CHECKED):
        stream_record(node, i * step, 100.0 + i * 0.02)
    assert node.lost_radio == lost


def test_a_lossy_stream_keeps_its_divider_and_counts_its_losses() -> None:
    node = Node(NodeEntry(address=76))
    node.streaming("accel_angrate", 512)
    step = 512 * TICKS_PER_CLOCK
    sent = [i for i in range(4 * STEPS_CHECKED) if i % 3 != 1]  # every third one lost
    for i in sent:
        stream_record(node, i * step, 100.0 + i * 0.01)
    assert node.divider == 512
    assert node.lost_radio == len(set(range(sent[0], sent[-1])) - set(sent))


def test_a_timer_that_goes_back_is_a_reboot_for_the_supervisor() -> None:
    node = Node(NodeEntry(address=76))
    node.streaming("accel_angrate", 512)
    stream_record(node, 100 * TICKS_PER_SECOND, 1000.0)
    stream_record(node, 1 * TICKS_PER_SECOND, 1000.01)  # back by 99 s: a power-up
    assert node.reboots == 1 and node.take_timer_reset() and not node.take_timer_reset()


def test_time_is_the_sample_instant_and_a_step_of_the_host_clock_moves_it_by_the_step():
    """100 Hz, every packet 3 ms (the latency) plus its 40 bytes on the line after its
    sample: ``time`` is the sample's instant. Then NTP steps the UNIX clock 10 s ahead
    (the monotonic clock goes on): ``time`` moves by the 10 s and no more, and it keeps
    increasing."""
    byte_time = 10 / 115200
    node = Node(NodeEntry(address=76), byte_time=byte_time, latency=0.003)
    node.streaming("accel_angrate")
    unix, mono, start = 1.7e9, 5000.0, 12.0
    found = []
    for i in range(500):
        sampled = i * 0.01
        at = mono + sampled + 0.003 + 40 * byte_time + (0.02 if i % 7 else 0.0)
        step = 10.0 if i >= 400 else 0.0
        raw = encode_reply_packet(76, encode(0xC2, accel=(0.0, 0.0, -1.0),
                                             ang_rate=(0.0, 0.0, 0.0),
                                             timer=round((start + sampled) * TICKS_PER_SECOND)))
        payload = node.tally(raw, decode(raw, 7, len(raw) - 4), unix + at - mono + step, at)
        found.append(payload["time"] - (unix + sampled + step))
    assert max(abs(e) for e in found[100:]) < 1e-6
    assert node.status(time.time())["clock"]["locked"] is True
