"""When the serial line is over capacity (pure: fed bytes read at given times)."""

from __future__ import annotations

from gateway.daemon.station.lineload import AT_CAPACITY, ROOM, SPAN, LineLoad

CAPACITY = 11520.0


def run(line: LineLoad, shares: list[float], start: float = 0.0, read: int = 0) -> list[bool]:
    """Sample once a second, the line carrying each share in turn; ``over`` after each."""
    said = []
    for second, share in enumerate(shares):
        read += int(share * CAPACITY)
        line.sample(start + second + 1, read)
        said.append(line.over)
    return said


def test_a_full_line_is_over_capacity_once_a_span_of_it_is_seen() -> None:
    line = LineLoad(CAPACITY)
    line.sample(0.0, 0)
    said = run(line, [1.0] * 8)
    assert said.index(True) + 1 == 0.8 * SPAN  # (judged from four fifths of a span on)
    assert line.share == 1.0
    assert line.reason() == "line over capacity: 100% of 11520 B/s: sample times unreliable"


def test_a_busy_line_under_capacity_is_never_over_it() -> None:
    line = LineLoad(CAPACITY)
    line.sample(0.0, 0)
    # 90%, with a stall of a whole second and its catching up (what bench/timesync.py does)
    assert not any(run(line, [0.9, 0.9, 0.0, 1.0, 1.0, 0.9, 0.9, 0.9, 0.9] * 4))


def test_over_capacity_has_room_again_only_below_room() -> None:
    line = LineLoad(CAPACITY)
    line.sample(0.0, 0)
    run(line, [1.0] * 6)
    assert line.over
    between = (AT_CAPACITY + ROOM) / 2
    read = int(6 * CAPACITY)
    assert all(run(line, [between] * 10, 6.0, read))  # no flapping between the two
    read += int(10 * between * CAPACITY)
    assert not run(line, [0.5] * 6, 16.0, read)[-1]


def test_the_bytes_per_second_are_over_the_last_span() -> None:
    line = LineLoad(CAPACITY)
    assert line.bytes_per_s(0.0, 0) == 0.0
    for second in range(10):
        line.sample(float(second), second * 1000)
    assert line.bytes_per_s(10.0, 10_000) == 1000.0


def replayed(line: LineLoad, reads: list[tuple[float, int]]) -> list[bool]:
    """Feed a replay's reads, (recorded time, bytes); ``over`` after each."""
    said, read = [], 0
    for at, size in reads:
        line.replayed(at, read, 1.0)
        read += size
        said.append(line.over)
    return said


def test_a_replay_is_judged_on_its_recorded_times_however_fast_it_is_played() -> None:
    # 90% of the line for 20 recorded seconds, in reads of 100 bytes: the wall clock a
    # replay plays them by is not asked at all
    size = 100
    step = size / (0.9 * CAPACITY)
    reads = [(1000.0 + i * step, size) for i in range(int(20 / step))]
    line = LineLoad(CAPACITY)
    assert not any(replayed(line, reads))
    assert 0.85 < line.share < 0.95
    # at 135% it is over capacity, from four fifths of a span on, as live
    line = LineLoad(CAPACITY)
    said = replayed(line, [(at / 1.5, size) for at, size in reads])
    first = said.index(True)
    assert 0.8 * SPAN <= reads[first][0] / 1.5 - reads[0][0] / 1.5 <= 0.8 * SPAN + 1.0


def test_a_replay_whose_recorded_clock_goes_back_judges_the_next_run_afresh() -> None:
    line = LineLoad(CAPACITY)
    full = [(float(i) / 10, int(CAPACITY / 10)) for i in range(100)]
    assert replayed(line, full)[-1]
    # another run of the gateway (its host rebooted): its clock starts again lower
    assert line.replayed(3.0, 0, 1.0)  # changed: it has room until judged again
    assert not line.over
    # a silence of an hour: only its last span is sampled
    assert not line.replayed(3603.0, 0, 1.0)
    assert len(line._samples) <= SPAN + 2
