"""Timer unwrapping: device time never goes back, wraps are counted, missed wraps are
recovered from host time, and a restarted timer is told apart from a wrap."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aspp.timing import (
    TICKS_PER_SECOND,
    TIMER_MODULUS,
    WRAP_SECONDS,
    TimerUnwrapper,
    data_rate,
    sample_period,
    seconds_to_ticks,
    ticks_to_seconds,
)


def test_constants_match_the_reference():
    assert TICKS_PER_SECOND == 19_660_800
    assert WRAP_SECONDS == pytest.approx(218.45, abs=0.01)
    assert data_rate(512) == 100.0
    assert sample_period(170) == pytest.approx(1 / 301.18, rel=1e-3)
    assert ticks_to_seconds(seconds_to_ticks(12.5)) == 12.5


def test_continuous_stream_across_a_wrap_without_host_time():
    unwrap = TimerUnwrapper()
    start = TIMER_MODULUS - 3 * 196_608  # three 100 Hz samples before the wrap
    times = [unwrap.update((start + i * 196_608) % TIMER_MODULUS) for i in range(8)]
    assert times == sorted(times)
    assert times[-1] - times[0] == pytest.approx(7 * 0.01)
    assert unwrap.resets == 0


def test_missed_wraps_recovered_from_host_time():
    unwrap = TimerUnwrapper()
    t0 = seconds_to_ticks(100.0)
    unwrap.update(t0, host_time=5000.0)
    silent = 2 * WRAP_SECONDS + 40.0  # the node was silent across two wraps
    device = unwrap.update(seconds_to_ticks(100.0 + silent), host_time=5000.0 + silent)
    assert device == pytest.approx(100.0 + silent, abs=1e-6)
    assert unwrap.resets == 0


def test_a_reboot_is_a_reset_not_a_wrap_and_time_still_goes_forward():
    unwrap = TimerUnwrapper()
    before = unwrap.update(seconds_to_ticks(150.0), host_time=10.0)
    after = unwrap.update(seconds_to_ticks(0.3), host_time=10.5)  # rebooted
    assert unwrap.last_was_reset and unwrap.resets == 1
    assert after == pytest.approx(before + 0.5)
    following = unwrap.update(seconds_to_ticks(0.31), host_time=10.51)
    assert following == pytest.approx(after + 0.01)
    assert not unwrap.last_was_reset


def test_a_backlog_read_late_is_not_a_reboot():
    """The reader stalled for 3 s, then read what had queued up: the records carry
    their own times, 10 ms apart, though they all arrived at once."""
    unwrap = TimerUnwrapper()
    unwrap.update(seconds_to_ticks(40.0), host_time=100.0)
    late = [unwrap.update(seconds_to_ticks(40.0 + 0.01 * i), host_time=103.0)
            for i in range(1, 301)]
    assert unwrap.resets == 0
    assert late == pytest.approx([40.0 + 0.01 * i for i in range(1, 301)])


def test_rejects_values_that_are_not_a_timer():
    with pytest.raises(ValueError):
        TimerUnwrapper().update(TIMER_MODULUS)
    with pytest.raises(ValueError):
        TimerUnwrapper().update(-1)


@settings(max_examples=200, deadline=None)
@given(start=st.integers(0, TIMER_MODULUS - 1),
       steps=st.lists(st.floats(0.0, 150.0), min_size=1, max_size=50),
       jitter=st.floats(-0.2, 0.2))
def test_unwrapped_time_tracks_true_elapsed_time(start, steps, jitter):
    """Any gap shorter than the wrap period, with host time jittered by radio latency."""
    unwrap = TimerUnwrapper()
    true = start / TICKS_PER_SECOND
    first = unwrap.update(start, host_time=0.0)
    elapsed = 0.0
    for step in steps:
        elapsed += step
        device = unwrap.update(seconds_to_ticks(true + elapsed), host_time=elapsed + jitter)
        assert device - first == pytest.approx(elapsed, abs=1e-6)
    assert unwrap.resets == 0


_READING = st.one_of(
    st.tuples(st.just("any"), st.integers(0, TIMER_MODULUS - 1), st.floats(-5.0, 400.0)),
    # the timer advancing by about the host step, off by a little: where the fast
    # path's bound and _reconcile's tolerance meet, a host clock stepping back included
    st.tuples(st.just("near"), st.one_of(st.floats(-3.0, 3.0), st.floats(1.95, 2.0)),
              st.floats(-3.0, 3.0)))


@settings(max_examples=500, deadline=None)
@given(readings=st.lists(_READING, min_size=2, max_size=30))
def test_the_fast_path_agrees_with_reconciling_every_reading(readings):
    """update() skips _reconcile for the usual reading; for any readings at all (reboots,
    stalls, missed wraps, a host clock that steps back) it must give exactly what
    reconciling every reading gives."""
    def run() -> tuple[list[float], int]:
        unwrap, host, ticks, times = TimerUnwrapper(), 0.0, 0, []
        for kind, a, b in readings:
            if kind == "any":
                ticks, host = a, host + b
            else:
                host += b
                ticks = (ticks + seconds_to_ticks(b + a)) % TIMER_MODULUS
            times.append(unwrap.update(ticks, host_time=host))
        return times, unwrap.resets

    fast = run()
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr("aspp.timing._HALF_WRAP_SECONDS", -1.0)  # the fast path never taken
        assert run() == fast


def test_a_host_clock_stepping_back_is_left_to_reconcile():
    """Found by review. The host clock went 1 s back and the timer 0.995 s on: 1.995 s
    apart, beyond _reconcile's slack of 2 s + 1% of the -1 s elapsed. A reset, as it
    always was; the fast path must not take it."""
    unwrap = TimerUnwrapper()
    unwrap.update(0, host_time=100.0)
    unwrap.update(round(0.995 * TICKS_PER_SECOND), host_time=99.0)
    assert unwrap.resets == 1 and unwrap.last_was_reset
