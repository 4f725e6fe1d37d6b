"""The 0xFA stop policy, driven the way the gateway drives it: a clock and the packets
a node keeps sending."""

from __future__ import annotations

import random

import pytest

from aspp.stop import GaveUp, NoAnswer, Probe, SendStop, Stopped, StopPolicy, WaitUntil

PERIOD = 0.01  # 100 Hz


def drive(policy, stops_after_attempt, packet_loss=0.0, seed=0, horizon=30.0):
    """Simulate a node that streams every PERIOD until the given attempt gets through.
    Returns the final result and the commands sent."""
    rng = random.Random(seed)
    now, next_packet, streaming, sent = 0.0, PERIOD, True, []
    while now < horizon:
        action = policy.next_action(now)
        if isinstance(action, (Stopped, GaveUp)):
            return action, sent
        if isinstance(action, SendStop):
            sent.append(action.command.code)
            if action.attempt >= stops_after_attempt:
                streaming = False
            continue
        assert isinstance(action, WaitUntil) and action.deadline > now
        if streaming and next_packet < action.deadline:
            now = next_packet
            next_packet += PERIOD
            if rng.random() >= packet_loss:
                policy.packet_seen(now)
        else:
            now = action.deadline
    raise AssertionError("the policy never finished")


def test_first_stop_gets_through():
    result, sent = drive(StopPolicy(PERIOD), stops_after_attempt=1)
    assert isinstance(result, Stopped) and result.attempts == 1 and sent == [0xFA]
    assert result.elapsed == pytest.approx(0.15, abs=0.02)  # silence window, 15 periods min


def test_lost_stops_are_retried_then_the_long_form_is_tried():
    result, sent = drive(StopPolicy(PERIOD, short_attempts=3), stops_after_attempt=6)
    assert isinstance(result, Stopped) and result.attempts == 6
    assert sent == [0xFA, 0xFA, 0xFA, 0xC4, 0xFA, 0xC4]


def test_gives_up_on_a_node_that_never_stops():
    result, sent = drive(StopPolicy(PERIOD, max_attempts=5), stops_after_attempt=99)
    assert isinstance(result, GaveUp) and result.attempts == 5 and len(sent) == 5


def test_a_quiet_node_is_stopped_after_one_silence_window():
    policy = StopPolicy(PERIOD)
    assert isinstance(policy.next_action(0.0), SendStop)
    assert policy.next_action(0.1) == WaitUntil(policy.silence)
    assert policy.next_action(policy.silence) == Stopped(1, policy.silence)


def test_packets_already_in_flight_do_not_cost_an_attempt():
    policy = StopPolicy(PERIOD, latency=0.05)
    policy.next_action(0.0)
    policy.packet_seen(0.02)   # sent before the stop arrived
    action = policy.next_action(0.02)
    assert action == WaitUntil(0.02 + policy.silence)
    assert policy.attempts == 1


def test_long_form_reply_confirms_at_once():
    policy = StopPolicy(PERIOD)
    policy.next_action(0.0)
    policy.stop_confirmed(0.03)
    assert policy.next_action(0.03) == Stopped(1, 0.03)


def test_silence_window_scales_with_a_slow_rate():
    assert StopPolicy(1.0).silence == 5.0       # 1 Hz: five missed records
    assert StopPolicy(0.0033).silence == 0.15   # fast rates: the floor


@pytest.mark.parametrize("seed", range(20))
def test_half_of_the_stops_lost_still_stops(seed):
    """Under 50% 0xFA loss the policy keeps trying until the stream really stops."""
    rng = random.Random(seed)
    first_to_arrive = next(i for i in range(1, 100) if rng.random() < 0.5)
    result, _ = drive(StopPolicy(PERIOD, max_attempts=20), first_to_arrive,
                      packet_loss=0.05, seed=seed)
    if first_to_arrive <= 20:
        assert isinstance(result, Stopped) and result.attempts == first_to_arrive
    else:
        assert isinstance(result, GaveUp)


def test_invalid_configuration_raises():
    with pytest.raises(ValueError):
        StopPolicy(0.0)
    with pytest.raises(ValueError):
        StopPolicy(PERIOD, short_attempts=5, max_attempts=3)


def test_packets_queued_before_the_stops_ack_do_not_count():
    """On a saturated link the ACK waits behind buffered packets; silence is measured
    from the ACK, so those packets neither cost an attempt nor prove failure."""
    policy = StopPolicy(PERIOD, latency=0.05)
    assert isinstance(policy.next_action(0.0), SendStop)
    for t in (0.1, 0.2, 0.3):
        policy.packet_seen(t)  # still draining the base station's buffer
    policy.sent(0.3)            # the ACK arrives after them
    assert policy.next_action(0.31) == WaitUntil(0.3 + policy.silence)
    assert policy.next_action(0.3 + policy.silence) == Stopped(1, 0.3 + policy.silence)


# -- the node must be heard (issue 21: a node out of range is silent too) ---------------------


def test_a_node_not_known_to_stream_that_does_not_answer_is_sent_no_stop():
    policy = StopPolicy(PERIOD, check_reach=True, streaming=False)
    assert policy.next_action(0.0) == Probe()
    assert policy.next_action(0.05) == Probe()  # until the answer is reported
    policy.unanswered(0.1)
    assert policy.next_action(0.1) == NoAnswer(0, 0.1)
    assert policy.attempts == 0


def test_a_node_that_answers_the_probe_is_stopped_by_silence():
    policy = StopPolicy(PERIOD, check_reach=True, streaming=False)
    assert policy.next_action(0.0) == Probe()
    policy.answered(0.01)
    assert isinstance(policy.next_action(0.01), SendStop)
    assert policy.next_action(0.01 + policy.silence) == Stopped(1, 0.01 + policy.silence)


def test_records_during_the_probe_are_the_node_heard():
    policy = StopPolicy(PERIOD, check_reach=True, streaming=False)
    assert policy.next_action(0.0) == Probe()
    policy.packet_seen(0.01)
    policy.unanswered(0.1)  # (a ping lost on its way: the records say it is there)
    assert isinstance(policy.next_action(0.1), SendStop)


def test_a_stream_whose_records_arrive_after_the_stop_needs_no_probe():
    result, sent = drive(StopPolicy(PERIOD, check_reach=True), stops_after_attempt=2)
    assert isinstance(result, Stopped) and result.attempts == 2 and sent == [0xFA, 0xFA]


def test_a_stream_silent_from_the_stop_on_is_probed_after_the_silence():
    """Out of range just before the stop: the silence is no proof until it answers."""
    policy = StopPolicy(PERIOD, check_reach=True)
    assert isinstance(policy.next_action(0.0), SendStop)
    assert policy.next_action(0.1) == WaitUntil(policy.silence)
    assert policy.next_action(policy.silence) == Probe()
    policy.unanswered(policy.silence + 0.1)
    assert policy.next_action(policy.silence + 0.1) == NoAnswer(1, policy.silence + 0.1)


def test_an_answered_probe_confirms_the_silence():
    policy = StopPolicy(PERIOD, check_reach=True)
    policy.next_action(0.0)
    assert policy.next_action(policy.silence) == Probe()
    policy.answered(policy.silence + 0.01)
    assert policy.next_action(policy.silence + 0.01) == Stopped(1, policy.silence + 0.01)


def test_a_record_during_the_probe_means_the_stream_goes_on():
    policy = StopPolicy(PERIOD, check_reach=True, latency=0.05)
    policy.next_action(0.0)
    assert policy.next_action(policy.silence) == Probe()
    policy.packet_seen(policy.silence + 0.005)  # it came within reach, streaming
    policy.answered(policy.silence + 0.01)
    action = policy.next_action(policy.silence + 0.01)
    assert isinstance(action, SendStop) and action.attempt == 2


def test_the_long_forms_reply_is_the_node_heard():
    policy = StopPolicy(PERIOD, check_reach=True)
    policy.next_action(0.0)
    policy.stop_confirmed(0.03)
    assert policy.next_action(0.03) == Stopped(1, 0.03)
