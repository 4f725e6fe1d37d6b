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

Silence is proof only from a node that can hear the stop: a node out of range is silent
too (issue 21: "95 stopped" for a node out of range). With ``check_reach`` the policy
asks for that proof, and a node not heard ends in :class:`NoAnswer`:

* a stream that was arriving when the stop began, and whose records arrive after it,
  comes from a node within reach: its silence afterwards is the stop taking;
* the long form's 0xC4 reply is the node itself saying it stopped;
* otherwise nothing shows the node is there, and the policy asks for a :class:`Probe`:
  a question only the node can answer (the wireless ping: the base station says 02
  only if the node answered). A node not known to stream is probed before any stop
  is sent: one that does not answer is sent nothing it cannot hear. A stream that fell
  silent with none of its records seen after the stop is probed once the silence has
  lasted: the silence is the stop only if the node answers.
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


@dataclass(frozen=True)
class Probe:
    """Ask the node something only it can answer (a wireless ping) and report the
    answer with :meth:`StopPolicy.answered` or :meth:`StopPolicy.unanswered`."""


@dataclass(frozen=True)
class NoAnswer:
    """The node was never heard, and did not answer the probe: the stop is not
    confirmed (it may be out of range, and may still be streaming)."""

    attempts: int
    elapsed: float


StopAction = SendStop | WaitUntil | Probe | Stopped | GaveUp | NoAnswer


class StopPolicy:
    """When to send 0xFA, how long silence must last, when to use the long form.

    ``sample_period``: seconds between the node's records (divider / 51200).
    ``silence_periods``: how many missed records prove the stream has stopped.
    ``latency``: how late a record sent before the stop took effect may still arrive
    (radio, base station and USB queues) without counting against the attempt.
    ``check_reach``: silence proves the stop only once the node has been heard since
    the stop began (see the module's docstring); without it silence alone does, for a
    caller that knows the node is within reach.
    ``streaming``: whether the node's stream was arriving when the stop began; if not
    (with ``check_reach``) the node is probed before any stop is sent.
    """

    def __init__(self, sample_period: float, *, silence_periods: float = 5,
                 min_silence: float = 0.15, latency: float = 0.05,
                 short_attempts: int = 3, max_attempts: int = 12,
                 check_reach: bool = False, streaming: bool = True) -> None:
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
        self._result: Stopped | GaveUp | NoAnswer | None = None
        self._heard = not check_reach
        """The node was heard since the stop began (or need not be)."""
        self._probe_first = check_reach and not streaming

    def packet_seen(self, now: float) -> None:
        """A streamed record from the node arrived at ``now``."""
        self._heard = True
        if self._last_packet is None or now > self._last_packet:
            self._last_packet = now

    def answered(self, now: float) -> None:
        """The node answered the :class:`Probe`: it is within reach."""
        self._heard = True

    def unanswered(self, now: float) -> None:
        """The node did not answer the :class:`Probe`: unless it was heard meanwhile,
        the stop ends unconfirmed."""
        if self._result is None and not self._heard:
            started = now if self._started is None else self._started
            self._result = NoAnswer(self.attempts, now - started)

    def sent(self, now: float) -> None:
        """The last stop left the base station at ``now`` (its ACK arrived): packets
        before then were queued ahead of it and prove nothing. Without this call the
        time :meth:`next_action` returned the SendStop counts as the send."""
        if self.attempts and now > self._last_send:
            self._last_send = now

    def stop_confirmed(self, now: float) -> None:
        """The node answered the long form with continuous command 0."""
        self._heard = True
        if self._result is None and self._started is not None:
            self._result = Stopped(self.attempts, now - self._started)

    def next_action(self, now: float) -> StopAction:
        if self._result is not None:
            return self._result
        if self._started is None:
            self._started = now
        if self.attempts == 0:
            return Probe() if self._probe_first and not self._heard else self._send(now)
        quiet_since = self._last_send
        if self._last_packet is not None and self._last_packet > quiet_since:
            quiet_since = self._last_packet
        deadline = quiet_since + self.silence  # compared as computed: a caller that
        if now >= deadline:                      # waits until it must see it passed
            if not self._heard:
                return Probe()  # (asked again until the caller reports its answer)
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
