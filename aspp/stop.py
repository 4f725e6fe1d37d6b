"""Stopping a node's stream over a lossy radio: the 0xFA policy, as a pure object.

0xFA has no reply, and a node busy streaming often never hears it. So a stop is proven
only by silence: no packet from the node for a few sample periods. The policy says when
to send, what to send (0xFA; after a few failures the long form C4 C1 29 00 in turn,
whose 0xC4 reply is positive proof), how long to wait and when to give up. The caller
owns the clock and the port: it reports packets it sees and asks what to do next.

    policy = StopPolicy(sample_period=0.01)
    action = policy.next_action(now)      # SendStop -> write action.command.packet(node)
    policy.packet_seen(now)               # for each packet from the node
    ...                                    # until Stopped or GaveUp
"""

from __future__ import annotations

from dataclasses import dataclass

from .commands import Command, stop_continuous, stop_continuous_long


@dataclass(frozen=True)
class SendStop:
    """Send ``command`` to the node now; this is attempt number ``attempt``."""

    command: Command
    attempt: int


@dataclass(frozen=True)
class WaitUntil:
    """Nothing to do before ``deadline`` unless a packet from the node arrives."""

    deadline: float


@dataclass(frozen=True)
class Stopped:
    """The stream is silent (or the node confirmed the long-form stop)."""

    attempts: int
    elapsed: float


@dataclass(frozen=True)
class GaveUp:
    """The node kept streaming through every attempt."""

    attempts: int
    elapsed: float


StopAction = SendStop | WaitUntil | Stopped | GaveUp


class StopPolicy:
    """When to send 0xFA, how long silence must last, when to use the long form.

    ``sample_period``: seconds between the node's records (divider / 51200).
    ``silence_periods``: how many missed records prove the stream has stopped.
    ``latency``: how late a record sent before the stop took effect may still arrive
    (radio, base station and USB queues) without counting against the attempt.
    """

    def __init__(self, sample_period: float, *, silence_periods: float = 5,
                 min_silence: float = 0.15, latency: float = 0.05,
                 short_attempts: int = 3, max_attempts: int = 12) -> None:
        if not sample_period > 0:
            raise ValueError(f"sample_period must be positive, not {sample_period!r}")
        if not 1 <= short_attempts <= max_attempts:
            raise ValueError("need 1 <= short_attempts <= max_attempts")
        self.silence = max(min_silence, silence_periods * sample_period)
        self.latency = latency
        self.short_attempts = short_attempts
        self.max_attempts = max_attempts
        self.attempts = 0
        self._started: float | None = None
        self._last_send = 0.0
        self._last_packet: float | None = None
        self._result: Stopped | GaveUp | None = None

    def packet_seen(self, now: float) -> None:
        """A streamed record from the node arrived at ``now``."""
        if self._last_packet is None or now > self._last_packet:
            self._last_packet = now

    def sent(self, now: float) -> None:
        """The last stop left the base station at ``now`` (its ACK arrived): packets
        before then were queued ahead of it and prove nothing. Without this call the
        time :meth:`next_action` returned the SendStop counts as the send."""
        if self.attempts and now > self._last_send:
            self._last_send = now

    def stop_confirmed(self, now: float) -> None:
        """The node answered the long form with continuous command 0."""
        if self._result is None and self._started is not None:
            self._result = Stopped(self.attempts, now - self._started)

    def next_action(self, now: float) -> StopAction:
        if self._result is not None:
            return self._result
        if self._started is None:
            self._started = now
            return self._send(now)
        quiet_since = self._last_send
        if self._last_packet is not None and self._last_packet > quiet_since:
            quiet_since = self._last_packet
        deadline = quiet_since + self.silence  # compared as computed: a caller that
        if now >= deadline:                      # waits until it must see it passed
            self._result = Stopped(self.attempts, now - self._started)
            return self._result
        if self._last_packet is not None and self._last_packet > self._last_send + self.latency:
            if self.attempts >= self.max_attempts:
                self._result = GaveUp(self.attempts, now - self._started)
                return self._result
            return self._send(now)
        return WaitUntil(deadline)

    def _send(self, now: float) -> SendStop:
        self.attempts += 1
        self._last_send = now
        beyond_short = self.attempts - self.short_attempts
        long_form = beyond_short > 0 and beyond_short % 2 == 1
        return SendStop(stop_continuous_long() if long_form else stop_continuous(),
                        self.attempts)
