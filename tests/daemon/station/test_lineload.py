"""When the serial line is over capacity (pure: fed each bin's least lag of each node,
as the station takes them from its nodes). The line models behind it, a FIFO base
station over capacity and host stalls, are tests/daemon/station/test_line_queue.py."""

from __future__ import annotations

import math

from gateway.daemon.station.lineload import (
    CONFIRM,
    FLOOR_MIN_BINS,
    QUEUE_MIN,
    SPAN,
    LineLoad,
    Waited,
)

CAPACITY = 11520.0
FLOOR = {76: 0.0005, 77: 0.001, 78: 0.0}
"""Each node's least wait above its clock's line with no queue: its radio's."""


class Line:
    """A LineLoad and the waits its nodes show each bin: ``waits`` above their floors."""

    def __init__(self) -> None:
        self.bins: dict[int, float] = {}
        self.epochs = dict.fromkeys(FLOOR, 0)
        self.floor_seen = dict.fromkeys(FLOOR, True)
        self.held_error = 0.0
        self.line = LineLoad(CAPACITY, self._waits)
        self.now = 0.0
        self.read = 0

    def _waits(self) -> list[Waited]:
        bins, self.bins = self.bins, {}
        return [Waited(node, bins.get(node, math.inf), self.epochs[node],
                       self.floor_seen[node], self.held_error if self.line.over else 0.0)
                for node in FLOOR]

    def bin(self, wait: float | dict[int, float] | None, share: float = 0.9) -> bool:
        """One bin in which every node waited ``wait`` (None: nothing of theirs read);
        whether the line is over capacity after it."""
        if wait is not None:
            waits = wait if isinstance(wait, dict) else dict.fromkeys(FLOOR, wait)
            self.bins = {node: FLOOR[node] + w for node, w in waits.items()}
        self.now += 1.0
        self.read += int(share * CAPACITY)
        self.line.sample(self.now, self.read)
        return self.line.over

    def run(self, waits: list[float | None], share: float = 0.9) -> list[bool]:
        return [self.bin(w, share) for w in waits]


def settled() -> Line:
    """A line whose nodes' floors are known (a few ordinary bins)."""
    line = Line()
    assert not any(line.run([0.001, 0.0, 0.002, 0.0]))
    return line


def test_a_queue_growing_then_standing_full_is_over_capacity() -> None:
    line = settled()
    # 135% offered at a base station whose gaps keep the reads at 90% of the line
    said = line.run([0.12, 0.36, 0.36, 0.361, 0.358, 0.36], share=0.9)
    assert said == [False] * (CONFIRM - 1) + [True] * (7 - CONFIRM)
    assert line.line.reason() == ("line over capacity: the base station queues 360 ms of "
                                  "packets (90% of 11520 B/s read): sample times unreliable")


def test_a_host_stall_read_back_faster_than_the_line_is_never_over_capacity() -> None:
    line = settled()
    # 2 s read nothing; then the backlog at 130% of the line, its waits falling as the
    # host and the base station's queue behind it catch up
    said = line.run([None, None, 0.36, 0.29, 0.22, 0.15, 0.08, 0.01, 0.0], share=1.3)
    assert not any(said)
    assert not any(line.run([0.0] * 20, share=0.93))  # no band for a busy line to latch in


def test_waits_under_the_queues_threshold_are_an_ordinary_busy_line() -> None:
    line = settled()
    # a node behind three others' longest packets, every packet: 20 ms, for a minute
    assert not any(line.run([QUEUE_MIN * 0.7] * 60, share=0.97))


def test_one_node_waiting_is_its_radio_not_the_shared_queue() -> None:
    line = settled()
    assert not any(line.run([{76: 0.2, 77: 0.0, 78: 0.001}] * 10))


def test_a_line_over_capacity_has_room_again_once_the_queue_drained() -> None:
    line = settled()
    line.run([0.2, 0.36, 0.36, 0.36])
    assert line.line.over
    # the overload ends: the queue drains at the line's spare share
    said = line.run([0.30, 0.20, 0.10, 0.025, 0.001])
    assert said == [True, True, True, False, False]
    # and it is judged again from there, not latched
    assert not any(line.run([0.0] * 10, share=0.94))
    line.run([0.1, 0.3, 0.36, 0.36])
    assert line.line.over


def test_nodes_rebooted_while_held_say_room_when_their_waits_fall() -> None:
    line = settled()
    line.run([0.2, 0.36, 0.36, 0.36])
    for node in FLOOR:
        line.epochs[node] += 1  # their timers restarted: waits above a new line's
    # (placed at their first packets' arrival, behind the queue: waits from there)
    assert all(line.run([0.0, 0.0, 0.001]))  # no floor: held while their waits stand
    assert not line.bin(-0.33)  # the queue drained under them


def test_a_node_removed_and_added_again_is_a_new_line() -> None:
    """A node a reload removed and added again starts its device time over: its waits
    never compare with the old node's (its old floor held a line over capacity for
    days), and a node no longer there is forgotten."""
    line = settled()
    line.epochs[76] = "a new node"
    assert not any(line.run([{76: 5.0, 77: 0.0, 78: 0.0}] * 5))
    line.epochs[76] = 0
    FLOOR.pop(78)
    try:
        line.bin(0.0)
        assert set(line.line._tracks) == {76, 77}
    finally:
        FLOOR[78] = 0.0


def test_a_floor_is_only_taken_from_a_node_whose_clock_saw_one() -> None:
    """A gateway (re)started on a line already over capacity reads every packet behind
    the full queue: no floor is taken from waits of packets that all waited."""
    line = Line()
    line.floor_seen = dict.fromkeys(FLOOR, False)
    line.run([0.0] * 5)
    assert all(line.line._tracks[node].known_floor() is None for node in FLOOR)


def test_records_stopped_while_held_leave_nothing_queued_and_a_stall_says_nothing() -> None:
    line = settled()
    line.run([0.2, 0.36, 0.36, 0.36])
    assert line.bin(None, share=0.0)  # nothing read at all (the host stalled): held
    # bytes, no record: a slow node between its records, or its records dropped by the
    # full base station, says nothing; SPAN of it, the streams stopped
    assert all(line.run([None] * (int(SPAN) - 1), share=0.1))
    assert not any(line.run([None, None], share=0.1))


def test_the_base_station_gone_takes_its_queue() -> None:
    line = settled()
    line.run([0.2, 0.36, 0.36, 0.36])
    line.line.link_down()
    assert not line.line.over
    assert not line.bin(0.0)


def test_a_node_needs_a_few_free_bins_before_its_floor_counts() -> None:
    line = Line()
    # from its first bin on the nodes wait behind a full queue: no floor to judge by
    assert not any(line.run([0.36] * (FLOOR_MIN_BINS + 5)))


def test_the_bytes_per_second_are_over_the_last_span() -> None:
    line = LineLoad(CAPACITY)
    assert line.bytes_per_s(0.0, 0) == 0.0
    for second in range(10):
        line.sample(float(second), second * 1000)
    assert line.bytes_per_s(10.0, 10_000) == 1000.0


def test_bins_close_on_the_reads_clock_however_fast_a_replay_plays_them() -> None:
    # bins closed at the recorded seconds between reads, each with what was read
    # before it: the wall clock a replay plays them by is not asked at all, and the
    # live gateway closed the same ones
    closed: list[float] = []
    line = LineLoad(CAPACITY, lambda: closed.append(0.0) or ())
    size = 100
    step = size / (0.9 * CAPACITY)
    reads = [(1000.0 + i * step, size) for i in range(int(20 / step))]
    read = 0
    for at, size in reads:
        line.read(at, read, 1.0)
        read += size
    assert len(closed) == 20
    assert 0.85 < line.share < 0.95


def test_a_replay_whose_recorded_clock_goes_back_judges_the_next_run_afresh() -> None:
    line = Line()
    for second in range(4):  # floors known
        line.bins = dict(FLOOR)
        line.line.read(float(second), 0, 1.0)
    for second in range(4, 9):  # a queue standing full
        line.bins = {node: FLOOR[node] + 0.36 for node in FLOOR}
        line.line.read(float(second), 0, 1.0)
    assert line.line.over
    # another run of the gateway (its host rebooted): its clock starts again lower
    assert line.line.read(3.0, 0, 1.0)  # changed: it has room until judged again
    assert not line.line.over
    # a silence of an hour: only its last span is sampled
    assert not line.line.read(3603.0, 0, 1.0)
    assert len(line.line._samples) <= SPAN + 2


def test_a_long_overload_has_room_again_as_far_as_the_held_lines_may_have_gone() -> None:
    """An hour over capacity: the held lines may have gone as far as their drift's
    uncertainty over the hour (aspp.clock.NodeClock.held_error); the room allows it, so
    the line has room again once the queue drained."""
    line = settled()
    line.run([0.2, 0.36, 0.36, 0.36])
    assert all(line.run([0.36] * 3600))
    line.held_error = 0.12  # (33 ppm for an hour)
    assert not line.bin(0.10)


def test_a_line_behind_a_full_queue_from_the_start_is_over_capacity_by_its_bytes() -> None:
    """No node has shown its floor (every packet back to back behind the queue from the
    gateway's start), and the line reads at its baud rate: over capacity; room once the
    waits fall by the queue's threshold (the queue drained under the lines kept)."""
    line = Line()
    line.floor_seen = dict.fromkeys(FLOOR, False)
    said = line.run([0.0] * 8, share=1.0)
    assert not said[0] and said[-1]
    assert line.line.reason() == ("line over capacity: no node shows its floor (100% of "
                                  "11520 B/s read): sample times unreliable")
    assert line.bin(0.0, share=1.0)
    assert not line.bin(-0.3, share=0.7)
    # and a busy line under its baud rate, floors unseen, is no queue
    line = Line()
    line.floor_seen = dict.fromkeys(FLOOR, False)
    assert not any(line.run([0.0] * 10, share=0.93))


def test_a_queue_not_yet_confirmed_is_suspect_and_a_stall_is_not_for_long() -> None:
    line = settled()
    line.run([0.12, 0.36])
    assert line.line.suspect and not line.line.over
    line.bin(0.36)
    assert line.line.over and not line.line.suspect  # (confirmed: held, not paused)
    stalled = settled()
    stalled.run([None, None, 0.36])
    assert stalled.line.suspect  # (a stall's first bin looks like a queue's)
    stalled.bin(0.29)
    assert not stalled.line.suspect
    stalled.bin(0.36)
    stalled.line.link_down()
    assert not stalled.line.suspect



def reading(line: Line, at: float, wait: float) -> None:
    """A read at ``at`` as the station makes it: the bins due closed with what was read
    before it, then its records' waits (evidence for the next bin) and its bytes."""
    line.line.read(at, line.read, 1.0)
    line.bins = {node: FLOOR[node] + wait for node in FLOOR}
    line.read += 1000


def test_a_queues_evidence_runs_in_consecutive_bins_not_across_a_silence() -> None:
    """Two bins of a queue's evidence, then the streams stop (bytes read, no record)
    for SPAN, or nothing is read for longer than SPAN: the count starts over, so a host
    stall's one bin of waiting when they come back is no third bin (it confirmed over
    capacity, and the clocks stayed paused through the silence: an outside review)."""
    line = settled()
    line.run([0.2, 0.36])
    assert line.line.suspect
    line.bin(None, share=0.1)  # (a slow node's bin between its records: nothing)
    assert line.line.suspect
    line.run([None] * int(SPAN), share=0.1)  # the streams stopped: replies, no record
    assert not line.line.suspect
    assert not line.bin(0.36) and line.line.suspect  # (its first bin again)
    read = Line()  # the same through the reads, as the station closes bins
    for second in range(7):
        for tenth in range(10):
            reading(read, second + tenth / 10, 0.001 if second < 5 else 0.3)
    assert read.line.suspect
    # nothing read meanwhile (the host stalled): its backlog, read in the next bin,
    # stands as high as the stall was long, and cannot be the third bin
    at = 7.0 + 2 * SPAN
    reading(read, at, 2 * SPAN)
    for k in range(1, 20):
        reading(read, at + k / 10, 0.0)  # read back: at the floor again
        assert not read.line.over
    assert not read.line.suspect


def test_a_stall_between_a_queues_bins_ends_its_evidence() -> None:
    """Two bins of waiting, then the host stalled for seconds (no bin with anything
    read: a base station holding a queue sends all the while), then its backlog: one
    bin of waiting, then falling waits, is a stall's, never a queue (the count ran
    across the stall and confirmed over capacity: an outside review)."""
    for stall in (2.0, 3.0, 5.0, 6.0):
        line = Line()
        for second in range(7):
            for tenth in range(10):
                reading(line, second + tenth / 10, 0.001 if second < 5 else 0.3)
        assert line.line.suspect
        at = 6.9 + stall
        for k in range(30):  # the backlog read back, its waits falling
            reading(line, at + k * 0.1, max(stall - k * 0.2, 0.0))
            assert not line.line.over, (stall, k)



def test_a_queue_read_in_gaps_is_confirmed() -> None:
    """A real queue read by a host whose reads stop for a second at times (a port
    opened by URL, a TCP retransmit): the kernel keeps what comes, the queue's waits
    stand after each gap, and it is said over capacity, a bin later than without the
    gaps (a count reset at each bin with nothing read never said it: an outside
    review)."""
    line = Line()
    at = 0.0
    while at < 20.0:
        wait = 0.001 if at < 6.0 else 0.36
        if at >= 6.0 and at % 3.0 < 1.05:
            at += 1.05  # no read for 1.05 s, every 3 s
            continue
        reading(line, at, wait)
        at = round(at + 0.01, 2)
    assert line.line.over
