"""Where published messages go: the output contract, the table of outputs, and the
fan-out that gives each message to each of them.

An output is one module of this package with a ``make(needs)`` and a row of
:data:`OUTPUTS`: ZeroMQ (:mod:`.zeromq`), the MCAP recorder (:mod:`.recorder`), the
Foxglove live view (:mod:`.live`), Prometheus metrics (:mod:`.metrics`), Lab Streaming
Layer outlets (:mod:`.lsl`), MQTT (:mod:`.mqtt`). Its life is
the contract of :class:`Output`: built with all it needs (nothing is wired into it
afterwards), started, given each published message on the loop (``take``: never
blocks, awaits or raises; an output whose work is slow queues it, bounded, and drops
and counts what does not fit; one that raises all the same is contained by the
fan-out: counted in ``take_failures``, logged once a kind of error, and the other
outputs still get the message), given each status report (``report``), asked its
``status``, and closed with the rest against one deadline. An output never calls back
into a station: stations see the fan-out only as the protocols of
:mod:`gateway.daemon.station.outlet`.
"""

from __future__ import annotations

import asyncio
import importlib
import logging
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, NamedTuple

import zmq

from gateway.common.payloads import as_published
from gateway.common.topics import MARK_TOPIC, STATUS_TOPIC, parse, topic

from ..errors import StartupError
from .guard import Guard
from .message import Message

if TYPE_CHECKING:
    from gateway.common.curve import KeyPair

    from ..config import GatewayConfig
    from .frames import Frames

log = logging.getLogger("gx2.outputs")


class Output:
    """The contract every output keeps; each method's default does nothing."""

    name = ""
    """Its row's name in :data:`OUTPUTS` (set when it is built)."""
    takes_messages = True
    """False for an output that only reads the status reports (metrics): the per-record
    path then never calls it."""

    def start(self) -> None:
        """Start its worker, if it has one (on the loop, once every output is built)."""

    def take(self, message: Message) -> None:
        """A published message, on the loop: never blocks, awaits or raises. The
        message is shared by every output: keep it, never change it; its JSON is
        ``message.json()``, made once for all."""

    def report(self, status: Mapping[str, Any]) -> None:
        """The gateway's latest status report (on the loop, at least once a second)."""

    def status(self) -> dict[str, Any] | None:
        """What it says of itself in the status report (None: nothing)."""
        return None

    def close(self, seconds: float) -> None:
        """Stop within ``seconds``; called off the loop, beside every other output's."""


@dataclass(frozen=True)
class Needs:
    """Everything an output may be built with."""

    config: GatewayConfig
    context: zmq.Context[Any]
    """The gateway's ZeroMQ context (its sockets live on the loop)."""
    server: KeyPair | None
    """The gateway's CURVE key pair, when it has one."""
    metadata: Callable[[], dict[str, str]]
    """What a recording says about the gateway that made it."""
    guard: Guard = field(default_factory=Guard)
    """The outputs' one guard (:mod:`.guard`): an output's thread reports what raised
    in it there (``guard.of(name)``), as the fan-out does for a ``take``."""


class Row(NamedTuple):
    """An output's row of :data:`OUTPUTS`."""

    section: str
    """Its section of the configuration: it is built when that is there."""
    module: str
    """Its module in this package, imported only then."""
    in_status: bool
    """It says something of itself: the status report has its name as a key (its
    ``status()``; null when it is not configured)."""


OUTPUTS: dict[str, Row] = {
    "zeromq": Row("publish", "zeromq", in_status=False),  # (status' gateway section)
    "metrics": Row("metrics", "metrics", in_status=False),
    "live": Row("live", "live", in_status=True),
    "recording": Row("record", "recorder", in_status=True),
    "lsl": Row("lsl", "lsl", in_status=True),
    "mqtt": Row("mqtt", "mqtt", in_status=True),
}
"""Every output, by name, in the order they are built: one is built when its section
is configured, and only then is its module imported (prometheus-client takes 64 ms to
import and 1.8 MiB, foxglove-sdk more, pylsl loads liblsl)."""


FRAMES = "frames"
"""The guard's name for the frames made for records (:mod:`.frames`): no output of its
own, given to those that take messages."""
REPLAYED = "replay"
"""The guard's name for replayed records made again as the gateway published them
(``Outputs.replayed``): no output of its own; in status once one failed."""
FAILED_START_CLOSE_S = 1.0
"""Seconds a failed start may spend closing the outputs it had already built (the
metrics and live view servers each stop within 0.5 s)."""


def build(needs: Needs) -> dict[str, Output]:
    """The configured outputs, by name. A port one cannot bind: StartupError, with the
    outputs built before it closed (a server left listening would outlive the start
    that failed, in-process and in the log)."""
    built: dict[str, Output] = {}
    try:
        for name, (section, module, _) in OUTPUTS.items():
            configured = getattr(needs.config, section)
            if configured is None:
                continue
            make = importlib.import_module(f"{__name__}.{module}").make
            try:
                output: Output = make(needs)
            except (zmq.ZMQError, OSError) as error:
                endpoint = getattr(configured, "endpoint", section)
                raise StartupError(f"cannot bind {endpoint}: {error.strerror or error}") \
                    from None
            output.name = name
            built[name] = output
    except BaseException:
        close_built(built.values())
        raise
    return built


def close_built(outputs: Iterable[Output], seconds: float = FAILED_START_CLOSE_S) -> None:
    """Close outputs a start that failed had built: all at once, each in a daemon thread
    of its own, all waited for ``seconds`` at most (nothing else runs yet: the loop, if
    any, has nothing to do until the StartupError reaches the caller). A failure to
    close one is logged, never raised over the StartupError that is on its way."""
    def close(output: Output) -> None:
        try:
            output.close(seconds)
        except Exception as error:
            log.error("output %s: closing it failed: %s", output.name, error)
    closing = [threading.Thread(target=close, args=(output,), daemon=True,
                                name=f"gx2-close-{output.name}") for output in outputs]
    for thread in closing:
        thread.start()
    done_by = time.monotonic() + seconds
    for thread in closing:
        thread.join(max(0.0, done_by - time.monotonic()))


class Outputs:
    """The fan-out: each published message to every output that takes messages, and
    each status report to every output.

    ZeroMQ is the gateway's publication: its answer is the message's (published, or
    lost and counted by the node), and it is given the message last, after the outputs
    that keep or show it whatever ZeroMQ did with it. It takes the topic and payload
    as they are (it packs msgpack, no JSON): a gateway with no other output makes no
    :class:`Message` at all."""

    def __init__(self, outputs: Mapping[str, Output], frames: Frames | None = None,
                 guard: Guard | None = None) -> None:
        self.by_name = dict(outputs)
        self._frames = frames
        """Which records give a node's frame (:mod:`.frames`); None: none does."""
        self.guard = guard or Guard()
        self._publication: Any = self.by_name["zeromq"]
        """ZeroMQ's output (its send: the message's publication)."""
        publication = self._publication
        guarded = {name: output for name, output in self.by_name.items()
                   if output.takes_messages and output is not publication}
        self._takes = tuple(output.take for output in guarded.values())
        self.guarded = tuple(guarded) + ((FRAMES,) if frames is not None and guarded else ())
        """The outputs given each message under the fan-out's guard, by name (and
        FRAMES, the frames made for them)."""
        self.take_failures = self.guard.failures
        """Output name -> messages its code raised on (a bug, contained: the other
        outputs still got them), its ``take`` or its thread's (:mod:`.guard`)."""
        self._topics: dict[tuple[int, str], list[Any]] = {}
        """(node, record) -> [its topic, messages published on it, what makes its
        frame (None: it gives none)]."""
        self.reads_reports = any(type(output).report is not Output.report
                                 for output in self.by_name.values())
        """Some output reads the status reports: one is made each second at least."""

    def get(self, name: str) -> Output | None:
        return self.by_name.get(name)

    def guard_status(self) -> dict[str, dict[str, int]]:
        """Status's ``outputs``: each guarded output's ``take_failures``."""
        return {name: {"take_failures": self.take_failures.get(name, 0)}
                for name in (*self.guarded, *(n for n in self.take_failures
                                              if n not in self.guarded))}

    # -- the loop's side ----------------------------------------------------------------

    def publish(self, node: int, record: str, payload: dict[str, Any]) -> bool:
        """One record; False if ZeroMQ refused it (counted, never raised). A subscriber
        past its high-water mark loses messages silently inside PUB: it sees them as
        gaps in ``seq``."""
        key = (node, record)
        entry = self._topics.get(key)
        if entry is None:
            frames = self._frames
            entry = self._topics[key] = [topic(node, record), 0, frames and frames.maker(
                node, record)]
        # (_give, inlined: one call fewer a record, about 500 instructions of the
        # 85,000 a record takes, bench/instructions.py)
        if self._takes:
            message = Message(entry[0], payload)
            for take in self._takes:
                # (a try costs nothing on Python 3.11+ until it catches)
                try:
                    take(message)
                except Exception as error:  # (one output's bug, contained)
                    self._take_failed(take, message, error)
            if entry[2] is not None:  # its frame, after it, to the same outputs
                self._give_frame(entry[2], payload)
        if self._publication.send(entry[0], payload):
            entry[1] += 1
            return True
        return False

    def _give_frame(self, make: Callable[[dict[str, Any]], Message | None],
                    payload: dict[str, Any]) -> None:
        """A record's frame (:mod:`.frames`) to the outputs that take messages, not to
        ZeroMQ (its subscribers' topics are the records'). Making it is guarded as a
        ``take`` is: a frame that cannot be made is counted under FRAMES, and the
        record is published all the same."""
        try:
            frame = make(payload)
        except Exception as error:  # (a bug, contained)
            self.guard.failed(FRAMES, "failed to make the frame of a record", error)
            return
        if frame is None:
            return
        for take in self._takes:
            try:
                take(frame)
            except Exception as error:  # (one output's bug, contained)
                self._take_failed(take, frame, error)

    def published(self) -> dict[int, dict[str, int]]:
        """Messages published on each topic: node -> record name -> count."""
        counts: dict[int, dict[str, int]] = {}
        for (node, record), (_, count, _) in self._topics.items():
            if count:
                counts.setdefault(node, {})[record] = count
        return counts

    def status(self, payload: dict[str, Any]) -> bool:
        """A status report, published (the heartbeat's, a link's change)."""
        return self._give(STATUS_TOPIC, payload)

    def mark(self, payload: dict[str, Any]) -> bool:
        return self._give(MARK_TOPIC, payload)

    def replayed(self, name: str, payload: dict[str, Any]) -> bool:
        """A message of a recording, published again on its topic as it was recorded (a
        node's record counted as one published on that node's topic), a record as the
        gateway published it (:func:`~gateway.common.payloads.as_published`: its NaN
        back from the file's nulls, a matrix's derived fields where the file lacks
        them), for every output alike. Making it so is guarded as a ``take`` is
        (counted under REPLAYED): a payload it fails on is published as it was read,
        and the replay goes on."""
        found = parse(name)
        if found is None:
            return self._give(name.encode(), payload)
        try:
            payload = as_published(dict(payload))
        except Exception as error:  # (a bug or a case unforeseen, contained)
            self.guard.failed(REPLAYED, f"failed to read a record on {name} as published",
                              error)
        return self.publish(*found, payload)

    def _give(self, name: bytes, payload: dict[str, Any]) -> bool:
        if self._takes:
            message = Message(name, payload)
            for take in self._takes:
                try:
                    take(message)
                except Exception as error:  # (one output's bug, contained)
                    self._take_failed(take, message, error)
        return self._publication.send(name, payload)  # type: ignore[no-any-return]

    def _take_failed(self, take: Callable[[Message], None], message: Message,
                     error: Exception) -> None:
        """An output's ``take`` raised (it must not): counted for that output, logged
        once a kind of error, and the message still goes to every other output."""
        name = getattr(getattr(take, "__self__", None), "name", "") or "?"
        self.guard.failed(name, "failed to take a message on "
                          f"{message.topic.decode(errors='replace')}", error)

    def report(self, status: Mapping[str, Any]) -> None:
        """The gateway's latest status report, to every output."""
        for output in self.by_name.values():
            output.report(status)

    # -- life ---------------------------------------------------------------------------

    def start(self) -> None:
        for output in self.by_name.values():
            output.start()

    async def close(self, done_by: float) -> None:
        """Close every output at once, each in a thread of its own, all by ``done_by``
        (time.monotonic()): one slow to stop never shortens another's time."""
        loop = asyncio.get_running_loop()
        seconds = max(0.0, done_by - time.monotonic())
        closing = [loop.run_in_executor(None, output.close, seconds)
                   for output in self.by_name.values()]
        results = await asyncio.gather(*closing, return_exceptions=True)
        for output, result in zip(self.by_name.values(), results, strict=True):
            if isinstance(result, BaseException):
                log.error("output %s: closing it failed: %s", output.name, result)
