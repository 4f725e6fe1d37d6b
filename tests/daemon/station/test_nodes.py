"""A node on its own (the end-to-end tests drive it through a real pty): when its
stream falls silent, what its timer says of its rate, its losses and its reboots."""

from __future__ import annotations

import itertools
import random
import time

import pytest

from aspp.frame import encode_reply_packet
from aspp.records import decode, encode
from aspp.timing import TICKS_PER_CLOCK, TICKS_PER_SECOND, TIMER_MODULUS, WRAP_SECONDS
from gateway.daemon.config import NodeEntry
from gateway.daemon.station.lineload import LineLoad
from gateway.daemon.station.nodes import SILENCE_MIN, STEPS_CHECKED, Node, State


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


# -- issue 19: reboots, long outages and time through the conversion to UNIX seconds -----

FLOOR = 0.003
"""The least delay of a packet (what base_station.latency_ms gives the gateway)."""
STEP = 512 * TICKS_PER_CLOCK
"""A 100 Hz stream's timer step."""


class Stream:
    """A 100 Hz accel_angrate stream of one node into ``node``: each record sampled at
    a known instant (the host's monotonic clock) and read FLOOR and a little later."""

    def __init__(self, node: Node, seed: int = 1) -> None:
        self.node, self.rng = node, random.Random(seed)
        self.unix_minus_monotonic = 1.7e9

    def send(self, timer: float, sampled: float, record: str = "accel_angrate") -> dict:
        """One record with the timer at ``timer`` seconds, sampled at ``sampled``."""
        ticks = round(timer * TICKS_PER_SECOND) % TIMER_MODULUS
        fields = ({"accel": (0, 0, -1), "ang_rate": (0, 0, 0)} if record == "accel_angrate"
                  else {"roll": 0.0, "pitch": 0.0, "yaw": 0.0})
        raw = encode_reply_packet(self.node.address, encode(record, **fields, timer=ticks))
        at = sampled + FLOOR + self.rng.uniform(0.0, 0.0005)
        payload = self.node.tally(raw, decode(raw, 7, len(raw) - 4),
                                  at + self.unix_minus_monotonic, at)
        payload["truth"] = sampled + self.unix_minus_monotonic
        return payload

    def run(self, timer: float, sampled: float, count: int) -> list[dict]:
        return [self.send(timer + i * 0.01, sampled + i * 0.01) for i in range(count)]


def streaming_node() -> Node:
    node = Node(NodeEntry(address=76), byte_time=0.0, latency=FLOOR)
    node.streaming("accel_angrate", 512)
    return node


def test_a_quiet_reboot_whose_timer_lands_ahead_modulo_the_wrap_is_counted_and_timed():
    """Issue 19: up for 217.4 s (1 s short of the wrap), off for 10 s with the discovery
    packet lost, back at 100 Hz from a timer at 0: the first record's timer is 1 s ahead
    of the last one's modulo the wrap, 10 s less than the host clock advanced. It is a
    reboot, counted once, and ``time`` is each sample's instant from the first record
    on (taken for a backlog read late, it was 9 s early for a minute)."""
    node = streaming_node()
    stream = Stream(node)
    stream.run(WRAP_SECONDS - 4.0, 1000.0, 300)
    after = stream.run(0.01, 1000.0 + 2.99 + 10.0, 300)
    assert node.reboots == 1 and node.take_timer_reset()
    assert max(abs(p["time"] - p["truth"]) for p in after) < 1e-3
    assert node.lost_radio == 0, "the reboot counted as samples lost"
    devices = [p["device_time"] for p in after]
    assert devices == sorted(devices)


def test_an_announced_reboot_leaves_nothing_behind_for_the_next_one():
    """The discovery packet came, and the new timer landed ahead as above: the reboot is
    counted once, and a later reboot whose discovery is lost is counted too (the
    announcement, never matched by a timer that went back, used to swallow it)."""
    node = streaming_node()
    stream = Stream(node)
    stream.run(WRAP_SECONDS - 4.0, 1000.0, 300)
    node.rebooted()  # the discovery packet
    node.streaming("accel_angrate", 512)  # re-armed
    after = stream.run(0.01, 1000.0 + 2.99 + 10.0, 300)
    assert node.reboots == 1 and not node.take_timer_reset()
    assert max(abs(p["time"] - p["truth"]) for p in after[150:]) < 1e-3
    stream.run(0.01, 1000.0 + 2.99 + 10.0 + 3.0 + 0.5, 100)  # a battery swap, unannounced
    assert node.reboots == 2 and node.take_timer_reset()


@pytest.mark.parametrize("outage", [60, 120, 250])
def test_the_samples_an_outage_of_any_length_lost_are_counted(outage):
    """Issue 19: out of range for 120 s nothing was counted, for 250 s (past a wrap)
    3,154 of 24,999: the steps were taken from the raw timer, modulo its wrap, and
    10,000 missing or more ignored. From the device time they are exact."""
    node = streaming_node()
    stream = Stream(node)
    stream.run(150.0, 1000.0, 200)
    stream.run(150.0 + 1.99 + outage, 1000.0 + 1.99 + outage, 100)
    assert node.lost_radio == outage * 100 - 1
    assert node.reboots == 0


def test_time_is_strictly_increasing_through_the_conversion_to_unix_seconds():
    """A poll's reply in the same cycle as the stream's record has its timer: the clock
    gives it a time a nanosecond later, and UNIX seconds near 1.7e9 are 238 ns apart,
    so both got one ``time``; and the UNIX clock less the monotonic one moves by a
    fraction of a microsecond between reads. Each is now above the last. A step of
    the UNIX clock back (NTP) still moves ``time`` by the step."""
    node = streaming_node()
    stream = Stream(node)
    times = []
    for i in range(300):
        sampled = 1000.0 + i * 0.01
        times.append(stream.send(40.0 + i * 0.01, sampled)["time"])
        if i % 10 == 0:
            stream.unix_minus_monotonic -= 1e-7
            times.append(stream.send(40.0 + i * 0.01, sampled, "euler")["time"])
    assert all(b > a for a, b in itertools.pairwise(times)), "time stood still or went back"
    stream.unix_minus_monotonic -= 5.0
    stepped = stream.send(40.0 + 3.0, 1003.0)
    assert stepped["time"] - times[-1] == pytest.approx(0.01 - 5.0, abs=1e-3)


class Clock:
    """time.monotonic() for the node, moved by the test."""

    def __init__(self, now: float) -> None:
        self.now = now

    def monotonic(self) -> float:
        return self.now


@pytest.mark.parametrize("down_s, out_of_range_s", [(2.8, 0.0), (2.0, 1.5)])
def test_samples_missed_while_the_station_was_down_are_not_radio_loss(
        monkeypatch, down_s: float, out_of_range_s: float) -> None:
    """Issue 31: what a stream missed while its base station was down is
    ``lost_station_down``; what it missed after the station was back (the node out of
    range meanwhile) is still ``lost_radio``."""
    clock = Clock(1000.0)
    monkeypatch.setattr("gateway.daemon.station.nodes.time", clock)
    node = Node(NodeEntry(address=76))
    node.streaming("accel_angrate", 512)  # 100 Hz
    step = 512 * TICKS_PER_CLOCK
    for i in range(50):
        clock.now = 1000.0 + i * 0.01
        stream_record(node, i * step, clock.now)
    node.link_lost()
    clock.now += down_s
    node.link_back()
    node.streaming("accel_angrate", 512)  # re-armed by the supervisor meanwhile
    clock.now += out_of_range_s
    resumed = 49 + round((down_s + out_of_range_s) * 100)
    stream_record(node, resumed * step, clock.now)
    stream_record(node, (resumed + 1) * step, clock.now + 0.01)
    assert node.lost_station_down + node.lost_radio == resumed - 49 - 1
    assert node.lost_station_down == pytest.approx(down_s * 100, abs=1)
    assert node.lost_radio == pytest.approx(out_of_range_s * 100, abs=1)


def test_no_station_down_gap_across_a_reboot_or_a_stop() -> None:
    node = Node(NodeEntry(address=76))
    node.streaming("accel_angrate", 512)
    step = 512 * TICKS_PER_CLOCK
    for i in range(10):
        stream_record(node, i * step, 100.0 + i * 0.01)
    node.link_lost()
    node.link_back()
    node.polled()  # stopped once back: a stream started later has no gap to count
    node.streaming("accel_angrate", 512)
    stream_record(node, 5000 * step, 200.0)
    assert (node.lost_station_down, node.lost_radio) == (0, 0)


def test_a_floor_the_lock_takes_back_is_no_floor_for_the_lines_judge() -> None:
    """A 1 Hz node on a line already full: every packet waited behind the queue, but the
    first was read late against the packet before it, so the reader judged it free and
    its clock saw a floor until its lock (ten packets on) took it back. The line's judge
    had taken bins of that floor meanwhile: the node's waits start a new line for it
    (take_wait's epoch), and the judge, with no floor from any node, says the full line
    over capacity by its bytes (before: the stale floor stood, and it was never said)."""
    byte_time = 10 / 115200
    slow = Node(NodeEntry(address=78), byte_time=byte_time, latency=0.003)
    slow.streaming("accel_angrate", 65535)
    load = LineLoad(11520.0, lambda: [slow.take_wait()])
    first = slow.take_wait().epoch
    queue, mono, bytes_read, said = 0.3, 5000.0, 0, False
    for second in range(30):
        raw = encode_reply_packet(78, encode(0xC2, accel=(0.0, 0.0, -1.0),
                                             ang_rate=(0.0, 0.0, 0.0),
                                             timer=round(second * 1.0 * TICKS_PER_SECOND)))
        at = mono + second + 0.003 + queue + 40 * byte_time + (0.0007 if second == 0 else 0.0)
        line_free = at - 40 * byte_time - (0.0007 if second == 0 else 0.0)  # (behind one)
        slow.tally(raw, decode(raw, 7, len(raw) - 4), at + 1.7e9 - mono, at, line_free)
        for tenth in range(10):  # the line full: bins of 0.1 s, the bytes at its rate
            bytes_read += 1152
            if load.sample(mono + second + (tenth + 1) / 10, bytes_read) and load.over:
                said = True
        if second == 0:
            assert slow.clock.floor_seen  # (as its first packet showed it)
    assert not slow.clock.floor_seen
    assert said  # (the station then holds its clocks: not done here)
    assert slow.take_wait().epoch != first
