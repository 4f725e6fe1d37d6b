"""How each node is doing: OK, WARN or ERROR, with the reasons.

The verdict is what an operator would conclude from the status table, made once and
the same everywhere: status, the heartbeat, ``gx2ctl top``, ``gx2ctl status --check``
and the ``gx2_node_health`` metric. Losses and signal are judged over the recent past
(``health.window_s``, a minute by default) from each node's counters, sampled once a
second by :class:`Health`: nothing is added to the per-record path.

ERROR: the node delivers nothing (the link is down, it is unreachable, its stream is
silent). WARN: it delivers, but worse than it should (rate under its expected rate,
radio loss, weak signal, a clock estimate that has not locked, records the gateway
could not publish, reboots). Thresholds: :class:`~.config.HealthConfig`.

The gateway has a health of its own, judged the same way (:func:`judge_gateway`): its
recorder. ERROR while the recorder cannot write (the directory cannot be made, the disk
is full, an I/O error): publishing goes on, but nothing is kept, and monitoring must
hear of it (issue 20: a read-only directory and a full disk passed ``status --check``).
WARN while the recorder's queue overflowed within the window (the disk does not keep
up), or while an output failed to take messages within it (a bug the fan-out contained:
that output lost them, the others did not). ``gx2ctl status --check`` fails on each;
``gx2_gateway_health`` carries it. What the gateway owns is folded in (:mod:`.owned`:
a base station whose link is not up, an MQTT output that cannot reach its broker, each
an ERROR), here, once: the verdict status shows is the one whose changes are logged.

A base station has reasons of its own, in its map of status and among the gateway's
(named by the station when there are several), each a WARN: its line over capacity, and
a node it is not configured for that streams on its channel (:mod:`.station.heard`):
that node takes radio time from the configured ones, and its packets line time.
"""

from __future__ import annotations

import logging
import statistics
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any, NamedTuple, Protocol

from aspp.clock import FLOOR_NOISE
from gateway.common.protocol import HealthLevel as Level

from .config import HealthConfig
from .station.heard import Heard
from .station.lineload import LineLoad
from .station.nodes import Node, State

log = logging.getLogger("gx2.health")
NOT_LOCKED = "clock not locked"
"""A node's reason while its clock's line stands on its first second of packets."""

SAMPLE_PERIOD = 1.0
"""Seconds between samples of the counters (the daemon's tick)."""
LINE_OVER_CAPACITY = "line over capacity: sample times unreliable"
"""A streaming node's reason while its serial line is over capacity (:mod:`.lineload`)."""


LEVELS = list(Level)
"""The levels, least severe first."""


class Verdict(NamedTuple):
    level: Level
    reasons: tuple[str, ...]


FAILED = {State.UNKNOWN: "base station not open yet", State.LINK_DOWN: "link down",
          State.UNREACHABLE: "unreachable", State.SILENT: "silent"}
"""States in which a node delivers nothing: ERROR, for that reason alone."""
RETRIED = (State.ARMING, State.REBOOTED)
"""States the supervisor passes a failed node through while it tries again: it stays
ERROR (its ``trouble``) until it streams, so the verdict does not flap with each try."""
MIN_SPAN = 1.0
"""Seconds of a stream before its rate over the window is measured at all."""


class Recent(NamedTuple):
    """One node's counters over the recent past."""

    seconds: float
    received: int
    lost_radio: int
    lost_gateway: int
    reboots: int
    rssi: float | None
    """Median of its RSSI, sampled once a second while records arrive."""
    stream_seconds: float = 0.0
    """How much of the window its stream has been running (since it last started)."""
    stream_received: int = 0
    """Records received in that time."""

    @property
    def rate_hz(self) -> float | None:
        """Records a second since its stream started, within the window (None before a
        second of it): steadier than the last 2 s, and measured on the monotonic clock."""
        if self.stream_seconds < MIN_SPAN:
            return None
        return self.stream_received / self.stream_seconds

    @property
    def loss_percent(self) -> float | None:
        """Share of the samples its stream sent that were lost over the radio."""
        sent = self.received + self.lost_radio
        return 100 * self.lost_radio / sent if sent else None

    def status(self) -> dict[str, Any]:
        loss = self.loss_percent
        rate = self.rate_hz
        return {"seconds": round(self.seconds, 1), "received": self.received,
                "rate_hz": None if rate is None else round(rate, 2),
                "lost_radio": self.lost_radio,
                "lost_radio_percent": None if loss is None else round(loss, 2),
                "lost_gateway": self.lost_gateway, "reboots": self.reboots,
                "rssi": None if self.rssi is None else round(self.rssi, 1)}


class _Sample(NamedTuple):
    at: float
    received: int
    lost_radio: int
    lost_gateway: int
    reboots: int
    rssi: int | None
    """Its last RSSI, if a record arrived since the sample before."""


class Window:
    """One node's counters, sampled over the last ``seconds`` (and one sample before,
    so that the window spans its whole length once it has run that long)."""

    def __init__(self, seconds: float) -> None:
        self.seconds = seconds
        self._samples: deque[_Sample] = deque()

    def sample(self, node: Node, now: float) -> None:
        last = self._samples[-1].received if self._samples else 0
        self._samples.append(_Sample(now, node.packets, node.lost_radio, node.lost_gateway,
                                     node.reboots,
                                     node.rssi if node.packets != last else None))
        while len(self._samples) > 1 and self._samples[1].at <= now - self.seconds:
            self._samples.popleft()

    def recent(self, node: Node, now: float) -> Recent:
        """Its counters since the window's first sample, up to ``now``."""
        if not self._samples:
            return Recent(0.0, 0, 0, 0, 0, None)
        first = self._samples[0]
        heard = [s.rssi for s in self._samples if s.rssi is not None and s is not first]
        # the stream's part: from the first sample since it started
        start = next((s for s in self._samples if s.at >= node.stream_started), None)
        streamed = (now - start.at, node.packets - start.received) if start else (0.0, 0)
        return Recent(now - first.at, node.packets - first.received,
                      node.lost_radio - first.lost_radio,
                      node.lost_gateway - first.lost_gateway, node.reboots - first.reboots,
                      statistics.median(heard) if heard else None, *streamed)


FLOOR_NEVER_SEEN_S = 3.0
"""Device seconds of a locked line that never saw its floor before it is said: such a
node is late by a wait no packet shows (up to a packet's time on the line), at once,
unlike a floor seen and then unseen, whose bound grows slowly (floor_unseen_s)."""


def unseen_after(node: Node) -> float:
    """Device seconds of a floor unseen (or never seen) before its node says so."""
    if node.clock.floor_seen:
        return node.floor_unseen_s
    return min(FLOOR_NEVER_SEEN_S, node.floor_unseen_s)


def clock_reasons(node: Node) -> list[str]:
    """What its clock says of ``time``, from its line's first packets on: held with its
    line over capacity (once the line kept may be off), its floor unseen past
    floor_unseen_s (with the bound), or never seen since its line started."""
    clock = node.clock
    if clock.held:
        # (while the line kept is still within the floor's noise of where it was, time
        # is as good as before the hold: the station's WARN says the line is over
        # capacity, and the node's says so once its time may be off, or at once if its
        # floor had gone unseen long enough to be said when the hold began; or at once
        # if it was not locked then: its line stands on its first packets, and those
        # may have waited in the queue the hold is for, as a node rebooted, released or
        # added while the queue was still being confirmed does: ``time`` 360 ms late
        # and nothing said for 15 s, held_error growing from 0; an outside review)
        error, age = clock.held_error(), clock.held_floor_age
        unseen = age is not None and age >= unseen_after(node)
        return [LINE_OVER_CAPACITY] if error is None or age is None \
            or error > FLOOR_NOISE or unseen else []
    age = clock.floor_age
    if age is None:  # (not locked yet: judge() says so once the stream settled)
        return []
    if age < unseen_after(node):
        return []
    if clock.floor_seen:
        if (late := node.floor_unseen()) is None:
            return []
        return [f"clock floor unseen for {age:.0f} s: time may be late by up to "
                f"{late * 1e3:.1f} ms"]
    return [f"clock floor never seen in {age:.0f} s: its packets may wait behind another "
            "node's, and time may be late by that wait"]


def judge(node: Node, recent: Recent, now: float, limits: HealthConfig) -> Verdict:
    """The node's health at ``now`` (``time.monotonic()``), from its state, its stream
    and its recent counters."""
    failed = FAILED.get(node.state)
    if failed is None and node.trouble is not None and node.state in RETRIED:
        failed = node.trouble  # (being armed again after a failure: not out of it yet)
    if failed is not None:
        return Verdict(Level.ERROR, (failed,))
    reasons = []
    expected, rate = node.expected_hz, recent.rate_hz
    settled = expected is not None and now - node.stream_started >= limits.settle_s
    # (a record more or less in the span is how it was sampled, not a slow stream)
    if settled and rate is not None and rate < (
            expected * (1 - limits.rate_under_percent / 100) - 1 / recent.stream_seconds):
        reasons.append(f"rate {rate:.1f} Hz of {expected:.4g} in "
                       f"{recent.stream_seconds:.0f} s")
    if expected is not None and node.clock.points and node.clock.floor_age is None \
            and not node.clock.held:  # (a node polled, not streaming, has no line to lock)
        # (a line's first second, from its first packet: the line stands on those few
        # packets, and whether one of them showed the floor is no proof: in the fault
        # soak, nodes powered up together or released from a queue were 0.5 to 3.4 ms
        # late in that second, "floor seen" by packets as late as the line; a start
        # WARNs for that second, as a receiver says "no fix" until it has one)
        reasons.append(NOT_LOCKED)
    if expected is not None:
        # (what the clock says is true from its first packets: a node back from a reboot
        # behind another's packets was 3.9 ms late, and said nothing while it settled)
        reasons.extend(clock_reasons(node))
    window = f"in {recent.seconds:.0f} s"
    if recent.seconds >= min(limits.window_s, limits.settle_s):  # enough to go by
        loss = recent.loss_percent
        if loss is not None and loss > limits.radio_loss_percent:
            reasons.append(f"radio loss {loss:.1f}% {window}")
        if recent.rssi is not None and recent.rssi < limits.weak_rssi_dbm:
            reasons.append(f"RSSI {recent.rssi:.0f} dBm")
    if recent.lost_gateway:
        reasons.append(f"{recent.lost_gateway} not published {window}")
    if recent.reboots:
        reasons.append(f"{recent.reboots} reboot{'s' if recent.reboots > 1 else ''} "
                       f"{window}")
    return Verdict(Level.WARN if reasons else Level.OK, tuple(reasons))


class Recording(Protocol):
    """What the gateway's health reads of its recorder (:class:`~.recorder.Recorder`)."""

    @property
    def overflowed(self) -> int:
        """Messages dropped so far because its queue was full."""

    @property
    def failure(self) -> str:
        """Why it cannot write now; "" while it writes."""


def judge_gateway(failure: str, overflowed: int, seconds: float) -> Verdict:
    """The gateway's own health: its recorder's ``failure`` now, and what its queue
    dropped (``overflowed``) over the last ``seconds``."""
    if failure:
        return Verdict(Level.ERROR, (f"recording failed: {failure}",))
    if overflowed:
        return Verdict(Level.WARN, (f"recording dropped {overflowed} messages in "
                                    f"{seconds:.0f} s: its queue was full (the disk does "
                                    "not keep up)",))
    return Verdict(Level.OK, ())


def unconfigured_streams(heard: Heard, now: float) -> list[str]:
    """A reason for each node that streams on the channel though it is not configured
    (``now``: ``time.monotonic()``)."""
    return [f"node {node.address} (not configured) streams {node.record} at {rate:.4g} Hz "
            "on its channel" for node, rate in heard.streaming(now)]


def station_reasons(line: LineLoad, heard: Heard, now: float) -> list[str]:
    """Why a base station is not all well (each a WARN): its line over capacity, and
    the nodes it is not configured for that stream on its channel."""
    return [*([line.reason()] if line.over else []), *unconfigured_streams(heard, now)]


def take_failed(output: str, count: int, seconds: float) -> str:
    """The gateway's WARN reason for an output that failed to take ``count`` messages
    over the last ``seconds`` (the fan-out logged the first of each kind of error)."""
    return (f"output {output} failed to take {count} message{'s' if count > 1 else ''} in "
            f"{seconds:.0f} s: a bug, contained (the other outputs got them; the log says "
            "what)")


def _trim(samples: deque[tuple[float, Any]], now: float, seconds: float) -> None:
    """Keep the samples of the last ``seconds``, and the one before them."""
    while len(samples) > 1 and samples[1][0] <= now - seconds:
        samples.popleft()


class Health:
    """Every node's window and verdict, the gateway's own, and the link's recent
    throughput."""

    def __init__(self, nodes: Iterable[Node], limits: HealthConfig,
                 lines: Iterable[tuple[str | None, LineLoad]] = (),
                 recorder: Recording | None = None,
                 take_failures: Mapping[str, int] | None = None,
                 heard: Iterable[tuple[str | None, Heard]] = (),
                 owned: Callable[[], Sequence[str]] | None = None) -> None:
        self.limits = limits
        self.nodes = list(nodes)
        self._windows = {node.address: Window(limits.window_s) for node in self.nodes}
        self._verdicts: dict[int, Verdict] = {}
        self.lines = list(lines)
        """Each base station's serial line, with its name (None for a gateway's only
        one): a line over capacity is a WARN of the gateway's."""
        self.heard = list(heard)
        """Each base station's unconfigured nodes heard, with its name (as ``lines``):
        one that streams is a WARN of the gateway's."""
        self.recorder = recorder
        """The gateway's recorder, if it records: what its own health is judged by."""
        self._overflows: deque[tuple[float, int]] = deque()
        self.take_failures = take_failures
        """Output name -> messages its take raised on (the fan-out's count, kept up to
        date by it)."""
        self._failures: deque[tuple[float, dict[str, int]]] = deque()
        self.owned = owned
        """Why what the gateway owns delivers nothing now (:func:`.owned.owned_reasons`
        of its stations and outputs), each an ERROR of the gateway's."""
        self._gateway = Verdict(Level.OK, ())

    def sample(self, now: float) -> None:
        """Once a second: sample every counter, and log each node whose health changed
        (and the gateway, if its own did)."""
        if self.recorder is not None:
            if not self._overflows:  # (what overflowed before the first sample counts)
                self._overflows.append((now, 0))
            self._overflows.append((now, self.recorder.overflowed))
            _trim(self._overflows, now, self.limits.window_s)
        if self.take_failures is not None:
            if not self._failures:  # (what failed before the first sample counts)
                self._failures.append((now, {}))
            self._failures.append((now, dict(self.take_failures)))
            _trim(self._failures, now, self.limits.window_s)
        verdict, before = self.gateway(now), self._gateway
        self._gateway = verdict
        if verdict.level != before.level:
            log.log(logging.INFO if verdict.level is Level.OK else logging.WARNING,
                    "gateway health %s -> %s%s", before.level, verdict.level,
                    f": {'; '.join(verdict.reasons)}" if verdict.reasons else "")
        for node in self.nodes:
            self._windows[node.address].sample(node, now)
            verdict = self.verdict(node, now)
            before = self._verdicts.get(node.address)
            self._verdicts[node.address] = verdict
            # (a line's first second, said not locked alone, is a node acquiring its
            # clock, as a receiver's "no fix": every start, power-up and release has
            # one; a warning each time taught users to ignore them. Logged at INFO,
            # and a WARN that grows another reason during it warns then)
            acquiring = (NOT_LOCKED,)
            grew = before is not None and before.reasons == acquiring \
                and verdict.level is Level.WARN and verdict.reasons != acquiring
            if before is not None and (verdict.level != before.level or grew):
                quiet = verdict.level is Level.OK or verdict.reasons == acquiring
                log.log(logging.INFO if quiet else logging.WARNING,
                        "node %s health %s -> %s%s", node.label, before.level,
                        verdict.level, f": {'; '.join(verdict.reasons)}"
                        if verdict.reasons else "")

    def add(self, node: Node) -> None:
        """A node added by a reload: judged from now on."""
        self.nodes.append(node)
        self._windows[node.address] = Window(self.limits.window_s)

    def remove(self, address: int) -> None:
        """A node removed by a reload: forgotten, its window and its verdict."""
        self.nodes = [node for node in self.nodes if node.address != address]
        self._windows.pop(address, None)
        self._verdicts.pop(address, None)

    def recent(self, node: Node, now: float) -> Recent:
        return self._windows[node.address].recent(node, now)

    def gateway(self, now: float) -> Verdict:
        """The gateway's health at ``now`` (``time.monotonic()``): its own, and what it
        owns folded in."""
        recorder = self.recorder
        verdict = Verdict(Level.OK, ())
        if recorder is not None:
            overflowed, seconds = 0, 0.0
            if self._overflows:
                at, before = self._overflows[0]
                overflowed, seconds = recorder.overflowed - before, now - at
            verdict = judge_gateway(recorder.failure, overflowed, seconds)
        if self.take_failures is not None and self._failures:
            at, before_counts = self._failures[0]
            failed = [take_failed(name, count - before_counts.get(name, 0), now - at)
                      for name, count in self.take_failures.items()
                      if count > before_counts.get(name, 0)]
            if failed:
                verdict = Verdict(max(verdict.level, Level.WARN, key=LEVELS.index),
                                  (*verdict.reasons, *failed))
        full = [line.reason() if name is None else f"base station {name}: {line.reason()}"
                for name, line in self.lines if line.over]
        full += [why if name is None else f"base station {name}: {why}"
                 for name, heard in self.heard for why in unconfigured_streams(heard, now)]
        if full:
            verdict = Verdict(max(verdict.level, Level.WARN, key=LEVELS.index),
                              (*verdict.reasons, *full))
        owned = self.owned() if self.owned is not None else ()
        if owned:  # (the worst there is: every reason, the owned first)
            verdict = Verdict(Level.ERROR, (*owned, *verdict.reasons))
        return verdict

    def gateway_status(self, now: float) -> dict[str, Any]:
        """What status adds to the gateway's map."""
        verdict = self.gateway(now)
        return {"health": str(verdict.level), "reasons": list(verdict.reasons)}

    def verdict(self, node: Node, now: float) -> Verdict:
        return judge(node, self.recent(node, now), now, self.limits)

    def status(self, node: Node, now: float) -> dict[str, Any]:
        """What status adds to a node's map."""
        recent = self.recent(node, now)
        verdict = judge(node, recent, now, self.limits)
        expected = node.expected_hz
        return {"expected_hz": None if expected is None else round(expected, 3),
                "recent": recent.status(), "health": str(verdict.level),
                "reasons": list(verdict.reasons)}
