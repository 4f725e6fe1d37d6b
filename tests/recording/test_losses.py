"""Samples lost, counted from the timer and from seq (gateway.recording.losses): pure
code, fed payloads shaped as the gateway publishes them, their device_time from the
gateway's own unwrapper (aspp.timing) where a timer restarts."""

from __future__ import annotations

import random

import pytest

from aspp.timing import TICKS_PER_CLOCK, TICKS_PER_SECOND, TIMER_MODULUS, TimerUnwrapper
from gateway.recording.losses import WINDOW, Counted, Losses
from gateway.recording.summary import Summary

DIVIDER = 512
STEP = DIVIDER * TICKS_PER_CLOCK
"""Timer ticks between two samples of a 100 Hz stream."""


def sample(i: int, seq: int, record: str = "accel_angrate", ticks: int | None = None) -> dict:
    """Sample ``i`` of a 100 Hz stream from a timer at 0, published as ``seq``."""
    ticks = i * STEP if ticks is None else ticks
    return {"record": record, "seq": seq, "timer": ticks % TIMER_MODULUS,
            "device_time": ticks / TICKS_PER_SECOND}


def counted(rows: list[tuple[int, str, dict]], ahead: int = WINDOW) -> dict[int, Counted]:
    """Each row's count, by its index in ``rows`` (node, record, payload)."""
    losses: Losses[int] = Losses(ahead)
    out = [c for i, (node, record, p) in enumerate(rows) for c in losses.add(node, record, p, i)]
    out += losses.finish()
    assert sorted(c.item for c in out) == list(range(len(rows))), "a row lost or repeated"
    return {c.item: c for c in out}


def test_a_lossy_stream_says_how_many_samples_are_missing_before_each_row():
    rng = random.Random(7)
    rows, truth, missing, seq = [], [], 0, 0
    for i in range(5000):
        if rng.random() < 0.26:
            missing += 1
            continue
        seq += 1
        rows.append((76, "accel_angrate", sample(i, seq)))
        truth.append(None if seq == 1 else missing)
        missing = 0
    got = counted(rows)
    assert [got[i].lost for i in range(len(rows))] == truth
    summary = Summary()
    for i in range(len(rows)):
        summary.add(got[i])
    assert summary.radio == sum(truth[1:]) > 1000 and summary.gateway == 0


def test_a_loss_in_the_first_step_is_counted_from_the_steps_after_it():
    # the shortest step so far would be two periods: the steps after it say it is one
    kept = [0, 2, *range(3, 40)]
    got = counted([(76, "euler", sample(i, n + 1, "euler")) for n, i in enumerate(kept)])
    assert [got[n].lost for n in range(4)] == [None, 1, 0, 0]
    # counted as records come (gx2ctl record's progress): nothing after it to learn from
    early = counted([(76, "euler", sample(i, n + 1, "euler")) for n, i in enumerate(kept)],
                    ahead=0)
    assert [early[n].lost for n in range(4)] == [None, 0, 0, 0]


def test_gateway_losses_are_told_apart_from_the_radios_by_seq():
    rows, seq = [], 0
    for i in range(100):
        if i in (10, 11):
            continue  # the radio lost them: no seq
        seq += 1
        if i == 40:
            rows.append((76, "temperatures", sample(i, seq, "temperatures", i * STEP + 1)))
            seq += 1  # a poll in between: a seq of its own, no gap
        if i in (60, 61, 62):
            continue  # the gateway lost them: their seq is missing too
        rows.append((76, "accel_angrate", sample(i, seq)))
    got = counted(rows)
    stream = [got[n] for n, (_, record, _) in enumerate(rows) if record == "accel_angrate"]
    after_radio = next(c for c in stream if rows[c.item][2]["timer"] == 12 * STEP)
    after_gateway = next(c for c in stream if rows[c.item][2]["timer"] == 63 * STEP)
    assert (after_radio.lost, after_radio.gateway, after_radio.radio) == (2, 0, 2)
    assert (after_gateway.lost, after_gateway.gateway, after_gateway.radio) == (3, 3, 0)
    summary = Summary()
    for c in stream:
        summary.add(c)
    assert (summary.received, summary.radio, summary.gateway) == (95, 2, 3)
    assert summary.line() == "radio: 2 lost (2.00%), gateway: 3 lost (3.00%)"


def test_the_first_row_after_a_reboot_is_unknown_and_counting_goes_on():
    # device_time as the gateway makes it: its unwrapper carries it on by the host's
    # clock over the restarted timer, so it does not go back
    unwrapper = TimerUnwrapper()
    rows, seq = [], 0
    for i in range(300):
        host = i / 100 if i < 150 else 3.0 + i / 100  # off for 3 s after sample 149
        ticks = i * STEP if i < 150 else (i - 150) * STEP + 1234  # the timer from ~0
        if i in (200, 201):
            continue
        seq += 1
        device = unwrapper.update(ticks % TIMER_MODULUS, host)
        rows.append((76, "accel_angrate", {"record": "accel_angrate", "seq": seq,
                                           "timer": ticks, "device_time": device}))
    assert unwrapper.resets == 1
    got = counted(rows)
    lost = [got[n].lost for n in range(len(rows))]
    assert lost[0] is None and lost[150] is None  # the first rows after power-ups
    assert lost[200] == 2  # (i = 202) counted again after the reboot
    assert set(lost[1:150] + lost[151:200] + lost[201:]) == {0}


def test_a_gateway_restart_and_a_stopped_stream_are_not_losses():
    rows = [(76, "euler", sample(i, i + 1, "euler")) for i in range(50)]
    # the gateway restarted: its seq begins again (its device_time too, from the timer)
    rows += [(76, "euler", sample(i, i - 59, "euler")) for i in range(60, 100)]
    # stopped for 5 s, then started: the node's continuous-mode reply, then its stream,
    # from the next cycle on; what it loses after the start counts
    seq = 41
    rows.append((76, "continuous_mode", {**sample(600, seq, "continuous_mode"),
                                         "continuous_command": 0xCE}))
    for i in range(601, 650):
        if i in (610, 611, 630, 631):
            continue
        seq += 1
        rows.append((76, "euler", sample(i, seq, "euler")))
        if i == 629:  # a start retried (its first reply lost): the stream goes on
            seq += 1
            rows.append((76, "continuous_mode", {**sample(i + 1, seq, "continuous_mode"),
                                                 "continuous_command": 0xCE}))
    got = counted(rows)
    lost = {n: got[n].lost for n, (_, record, _) in enumerate(rows) if record == "euler"}
    assert lost[50] is None  # seq went back: what came before is not known
    assert lost[91] == 0  # the first sample after the start
    by_timer = {rows[n][2]["timer"] // STEP: value for n, value in lost.items()}
    assert by_timer[612] == 2 and by_timer[632] == 2  # (the retried start's reply amid)
    assert sum(v for v in lost.values() if v) == 4 and lost[0] is None


def test_a_stream_started_after_a_reboot_still_says_the_reboot():
    rows = [(76, "euler", sample(i, i + 1, "euler")) for i in range(50)]
    # the node rebooted (its timer from 0 while device_time went on) and was started
    # again before it streamed
    restart = 50 * STEP + 3 * TICKS_PER_SECOND
    rows.append((76, "continuous_mode", {"seq": 51, "timer": 0, "device_time":
                                         restart / TICKS_PER_SECOND}))
    rows += [(76, "euler", {"seq": 52 + i, "timer": (i + 1) * STEP,
                            "device_time": (restart + (i + 1) * STEP) / TICKS_PER_SECOND})
             for i in range(20)]
    got = counted(rows)
    assert got[51].lost is None and {got[n].lost for n in range(52, 71)} == {0}


def test_polled_records_lose_nothing():
    rng = random.Random(3)
    # polled by hand every few seconds, and by a script every 0.3 s give or take a
    # cycle: steps that are no stream's period
    slow, fast, at = [], [], 0
    for n in range(40):
        at += rng.randint(150, 900)
        slow.append((76, "temperatures", sample(at, n + 1, "temperatures")))
    at = 0
    for n in range(200):
        at += rng.choice((29, 30, 30, 31, 60))
        fast.append((77, "euler", sample(at, n + 1, "euler")))
    got = counted(slow + fast)
    assert {c.lost for c in got.values()} == {None, 0}


def test_a_row_without_a_timer_is_unknown():
    got = counted([(76, "firmware_version", {"seq": 1, "version": 2113})])
    assert got[0].lost is None and got[0].radio == 0


@pytest.mark.parametrize("divider", [170, 512, 51200])
def test_every_rate_a_node_can_run_at_is_counted(divider):
    step = divider * TICKS_PER_CLOCK
    kept = [i for i in range(300) if i % 7 != 3]
    rows = [(76, "accel_angrate", {"seq": n + 1, "timer": (i * step) % TIMER_MODULUS,
                                   "device_time": i * step / TICKS_PER_SECOND})
            for n, i in enumerate(kept)]
    got = counted(rows)
    assert sum(got[n].lost or 0 for n in range(len(rows))) == 300 - len(kept)
