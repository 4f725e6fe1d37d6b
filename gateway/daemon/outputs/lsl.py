"""A Lab Streaming Layer outlet (``lsl:``): every node's records as LSL streams, so that
LabRecorder writes them into one XDF file beside the lab's EEG, EMG and motion capture.

One stream per node and record (``<prefix>-<node>-<record>``), made when its first
sample comes: float32, one channel per scalar of the record's fields (the timer and
the link fields left out), named as ``gx2ctl export`` names its columns, with units and
types in the stream's ``desc`` (docs/labrecorder.md). Each sample is stamped with the
gateway's ``time`` for it, put on LSL's clock (:class:`LslClock`): the instant the
node sampled it, never the moment it was pushed. Samples lost over the radio are not
invented: the stream has a gap there, as ``can_drop_samples`` says.

``take`` runs on the loop and only appends to a bounded deque (dropped and counted when
it is full); a thread of its own makes the outlets and pushes into liblsl, whose own
threads serve the inlets. A sample is made of each record alone: a field the record
lacks or holds NaN in is NaN in its channel, and a record no sample can be made of (a
foreign recording's text where a number goes) is dropped alone, counted and said
through the outputs' guard (:mod:`.guard`), never its batch with it. Imported only
when ``lsl:`` is configured, and pylsl only then (:func:`load_pylsl`).
"""

from __future__ import annotations

import array
import ctypes
import importlib
import logging
import math
import socket
import statistics
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from types import ModuleType
from typing import Any

from aspp.records import STREAMABLE
from aspp.timing import data_rate

from ..config import LslConfig
from ..errors import StartupError
from . import Message, Needs, Output
from .guard import Guard, Guarded
from .lslinfo import describe, node_name

log = logging.getLogger("gx2.lsl")

INSTALL_LIBLSL = (
    "lsl: needs pylsl and its liblsl: pip install 'gx2-gateway[lsl]' (its wheel ships "
    "liblsl on x86_64 Linux; elsewhere install liblsl from "
    "https://github.com/sccn/liblsl/releases or conda-forge and set PYLSL_LIB to it)")
WAKE_S = 0.02
"""Seconds the thread sleeps between pushes: a sample waits at most this long for
liblsl (LSL's own inlets pull in chunks of tens of milliseconds)."""
PENDING_S = 2.5
"""Seconds a new stream's samples wait for a status report that says it is its node's
stream (and so its rate): two reports at least. A record no report names by then (a
polled one) gets a stream of irregular rate."""
MAX_BUFFERED_S = 60
"""Seconds of samples an outlet keeps for an inlet that reads slowly (liblsl's
``max_buffered``; its default is six minutes)."""
CLOSE_S = 1.0


def load_pylsl() -> ModuleType:
    """pylsl, with liblsl loaded; StartupError in one line (INSTALL_LIBLSL) when it
    cannot be (pylsl missing, or no liblsl for this machine: it raises RuntimeError)."""
    try:
        return importlib.import_module("pylsl")
    except (ImportError, RuntimeError, OSError) as error:
        why = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise StartupError(f"{INSTALL_LIBLSL} ({why})") from None


def refusal() -> str | None:
    """Why ``lsl:`` could not start here (one line), or None: for ``--check``."""
    try:
        load_pylsl()
    except StartupError as error:
        return str(error)
    return None


class LslClock:
    """The gateway's ``time`` (UNIX seconds) put on LSL's clock.

    How ``time`` is made (gateway/daemon/station/nodes.py, ``Node.tally``): each node's
    line (aspp/clock.py) maps device time to ``time.monotonic()``, and the result goes
    out as ``monotonic estimate + (host_time - monotonic)``, the two clocks read one
    after the other at the packet's read. So ``time`` less the UNIX clock's offset from
    the monotonic clock is the sample's instant on the monotonic clock, exactly, and a
    step of the UNIX clock (NTP) moves ``time`` and that offset alike.

    LSL's clock, ``local_clock()``, is liblsl's ``lsl_local_clock``: C++'s
    ``std::chrono::steady_clock`` (liblsl, src/common.cpp), which is CLOCK_MONOTONIC on
    Linux, as Python's ``time.monotonic()`` is (PEP 418). The two are one clock then,
    but that is not assumed: their difference is measured once at start (``shift``,
    the median of a few bracketed reads; 0 here to a microsecond).

    An LSL timestamp is therefore ``time - (time.time() - time.monotonic()) + shift``,
    the UNIX offset read when the record is taken, on the loop, right after its read:
    the same offset the record's ``time`` was made with, but for the UNIX clock's slew
    between the two (NTP slews at 500 ppm at most: under a microsecond for the
    milliseconds between a read and its take)."""

    def __init__(self, local_clock: Callable[[], float]) -> None:
        self.shift = statistics.median(self._bracketed(local_clock) for _ in range(7))
        """LSL's clock less the monotonic clock (seconds)."""

    @staticmethod
    def _bracketed(local_clock: Callable[[], float]) -> float:
        before = time.monotonic()
        lsl = local_clock()
        after = time.monotonic()
        return lsl - (before + after) / 2

    @staticmethod
    def unix_offset() -> float:
        """The UNIX clock less the monotonic clock, now."""
        return time.time() - time.monotonic()

    def stamp(self, sample_time: float, unix_offset: float) -> float:
        return sample_time - unix_offset + self.shift


class Stream:
    """One node's record as one LSL outlet, and how a payload becomes its sample."""

    def __init__(self, pylsl: ModuleType, name: str, info: Any,
                 picks: list[tuple[str, int]], rate: float, named: str = "") -> None:
        self.name = name
        self.rate = rate
        self.node_name = named
        """The node's name its desc says (``gx2/name``): a new stream when it changes."""
        self.picks = picks
        """(field, index) of each channel: index -1 for a scalar field."""
        self.outlet = pylsl.StreamOutlet(info, max_buffered=MAX_BUFFERED_S)
        # (pylsl's StreamOutlet: ``obj`` its liblsl handle, ``do_push_chunk_n`` the C
        # function for a chunk of its format with a timestamp a sample)
        self._outlet_handle = self.outlet.obj
        self._push_chunk = self.outlet.do_push_chunk_n

    def sample(self, payload: Mapping[str, Any]) -> list[Any]:
        """The payload's channel values: NaN for a field it lacks or holds null in (a
        recording's NaN, which a replay gives back as NaN all the same)."""
        values: list[Any] = []
        for field, index in self.picks:
            value = payload.get(field)
            if value is None:
                values.append(math.nan)
            elif index < 0:
                values.append(value)
            elif isinstance(value[0], (list, tuple)):  # a matrix, row-major
                values.append(value[index // 3][index % 3])
            else:
                values.append(value[index])
        return values

    def push(self, floats: array.array[float], stamps: list[float]) -> None:
        """Samples (their channel values one after the other, float32) with their
        timestamps, into liblsl in one call: its C API's ``lsl_push_chunk_ftnp`` on
        flat arrays, as pylsl's own ``push_chunk`` ends, without the numpy conversion
        it goes through first (the thread's CPU at a saturated line: 0.85% of a core
        through ``push_chunk``, 0.53% this way; docs/performance-history.md, "LSL output")."""
        doubles = array.array("d", stamps)
        error = self._push_chunk(self._outlet_handle,
                                 ctypes.c_void_p(floats.buffer_info()[0]),
                                 ctypes.c_long(len(floats)),
                                 ctypes.c_void_p(doubles.buffer_info()[0]), ctypes.c_int(1))
        if error < 0:  # (liblsl's lsl_error_code_t)
            raise RuntimeError(f"liblsl refused the chunk (error {error})")


class LslOutput(Output):
    """``take`` on the loop; outlets and pushes in its thread."""

    def __init__(self, config: LslConfig, latency_ms: dict[str, float],
                 pylsl: ModuleType, guard: Guarded | None = None) -> None:
        self.pylsl = pylsl
        self._guard = guard or Guard().of("lsl")
        """Where a sample that cannot be made is counted and said (:mod:`.guard`)."""
        self.prefix = config.prefix
        self.capacity = config.queue
        self.latency_ms = latency_ms
        """Each station's base_station.latency_ms, by name (said in each desc)."""
        self.host = socket.gethostname()
        self.clock = LslClock(pylsl.local_clock)
        self._queue: deque[tuple[Message, float]] = deque()
        self._report: Mapping[str, Any] = {}
        """The latest status report (set on the loop; one reference, read whole)."""
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="gx2-lsl", daemon=True)
        self._streams: dict[tuple[int, str], Stream] = {}
        self._waiting: dict[tuple[int, str], tuple[float, list[tuple[Message, float]]]] = {}
        """Samples of a stream not made yet: since when, and them."""
        self.overflowed = 0
        """Samples the loop dropped: the queue was full."""
        self.skipped = 0
        """Records no stream carries: a command's reply (continuous_mode, a bias, an
        EEPROM word: not data), and a record without ``time``. Every record a node
        streams has a timer, and ``time`` from its first one, so this is never a
        sample: no timestamp could say when an untimed record was sampled, and one
        stamped with the host's clock would pass for a sample instant."""
        self.failed = 0
        """Samples dropped after the queue: liblsl refused them (an outlet that could
        not be made, a push that raised; logged once a stream), or no sample could be
        made of the record (counted and said by the guard)."""
        self._failed_streams: set[tuple[int, str]] = set()
        self.pushed = 0
        """Samples handed to liblsl (counted by the thread)."""

    # -- the loop's side --------------------------------------------------------------

    def take(self, message: Message) -> None:
        payload = message.payload
        command = payload.get("command")
        if command is None:
            return  # (the status, a mark)
        if command not in STREAMABLE or payload.get("time") is None:
            self.skipped += 1
            return
        queue = self._queue
        if len(queue) < self.capacity:
            queue.append((message, time.time() - time.monotonic()))
        else:
            self.overflowed += 1

    def report(self, status: Mapping[str, Any]) -> None:
        self._report = status

    def status(self) -> dict[str, Any]:
        streams = list(self._streams.values())
        return {"prefix": self.prefix, "streams": sorted(s.name for s in streams),
                "pushed": self.pushed, "queued": len(self._queue),
                "waiting": sum(len(w[1]) for w in list(self._waiting.values())),
                "dropped": self.overflowed + self.failed, "skipped": self.skipped}

    # -- the thread -------------------------------------------------------------------

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        try:
            while not self._stop.wait(WAKE_S):
                try:
                    self._push_queued()
                except Exception as error:  # (a bug: contained, and it goes on)
                    self._guard.failed("failed in its thread", error)
        finally:
            self._streams.clear()  # (each outlet is destroyed, its inlets told)

    def _push_queued(self) -> None:
        queue = self._queue
        batches: dict[tuple[int, str], list[tuple[Message, float]]] = {}
        while queue:
            item = queue.popleft()
            payload = item[0].payload
            batches.setdefault((payload["node"], payload["record"]), []).append(item)
        now = time.monotonic()
        for key, items in batches.items():
            stream = self._streams.get(key)
            if stream is not None and self._outdated(key, stream):
                del self._streams[key]
                stream = None
            if stream is not None:
                self._push(key, items)
            else:
                waiting = self._waiting.setdefault(key, (now, []))[1]
                room = max(0, self.capacity - len(waiting))
                waiting.extend(items[:room])
                self.overflowed += max(0, len(items) - room)
        for key in list(self._waiting):
            since, waiting = self._waiting[key]
            rate = self._rate(key)
            if rate is None and now - since < PENDING_S:
                continue
            del self._waiting[key]
            if self._open(key, waiting[0][0].payload, rate or 0.0):
                self._push(key, waiting)
            else:
                self.failed += len(waiting)

    def _node_status(self, node: int) -> Mapping[str, Any] | None:
        nodes = self._report.get("nodes") or ()
        return next((n for n in nodes if n.get("node") == node), None)

    def _outdated(self, key: tuple[int, str], stream: Stream) -> bool:
        """Its node's rate changed (gx2ctl rate), a record first seen polled is now
        streamed, or a reload renamed the node: a stream's nominal rate and desc are
        fixed, so a new one is made, with the same name and source_id (LabRecorder
        re-finds it)."""
        node = self._node_status(key[0])
        return (self._rate(key) not in (None, stream.rate)
                or (node is not None and node_name(node) != stream.node_name))

    def _rate(self, key: tuple[int, str]) -> float | None:
        """The stream's nominal rate, once a report says the record is its node's
        stream (None until then)."""
        node = self._node_status(key[0])
        if node is None or node.get("record") != key[1] or not node.get("divider"):
            return None
        return data_rate(node["divider"])

    def _open(self, key: tuple[int, str], payload: Mapping[str, Any], rate: float) -> bool:
        try:
            station = payload.get("station", "")
            node = self._node_status(key[0])
            name, info, picks = describe(self.pylsl, self.prefix, payload, node, rate,
                                         self.host, self.latency_ms.get(station))
            self._streams[key] = Stream(self.pylsl, name, info, picks, rate,
                                        node_name(node))
        except Exception as error:  # (liblsl's own refusal: said once)
            self._failed_once(key, f"cannot make its outlet: {error}")
            return False
        log.info("lsl: stream %s (%s)", name, f"{rate:g} Hz" if rate else "irregular rate")
        return True

    def _push(self, key: tuple[int, str], items: list[tuple[Message, float]]) -> None:
        """The samples of ``items`` into its stream, in one push: each made alone (a
        record no sample can be made of is dropped alone, through the guard)."""
        stream = self._streams[key]
        stamp = self.clock.stamp
        floats: array.array[float] = array.array("f")
        stamps: list[float] = []
        for message, offset in items:
            payload = message.payload
            try:
                at = stamp(payload["time"], offset)
                floats.fromlist(stream.sample(payload))  # (all of it, or nothing)
            except Exception as error:  # (a record no sample can be made of: alone)
                self.failed += 1
                self._guard.failed(f"failed to make a sample of {stream.name}", error)
                continue
            stamps.append(at)
        if not stamps:
            return
        try:
            stream.push(floats, stamps)
            self.pushed += len(stamps)
        except Exception as error:
            self.failed += len(stamps)
            self._failed_once(key, f"a push failed: {type(error).__name__}: {error}")

    def _failed_once(self, key: tuple[int, str], why: str) -> None:
        if key not in self._failed_streams:
            self._failed_streams.add(key)
            log.error("lsl: %s-%d-%s: %s (counted in status lsl.dropped; said once a "
                      "stream)", self.prefix, key[0], key[1], why)

    def close(self, seconds: float = CLOSE_S) -> None:
        """Stop the thread (its outlets destroyed with it) within ``seconds``."""
        self._stop.set()
        if self._thread.ident is not None:
            self._thread.join(max(0.0, seconds))
            if self._thread.is_alive():
                log.warning("lsl: its thread did not stop within %.1f s: left to the "
                            "process's exit", seconds)


def make(needs: Needs) -> LslOutput:
    config = needs.config
    assert config.lsl is not None
    latency = {station.name or "": station.latency_ms for station in config.stations}
    return LslOutput(config.lsl, latency, load_pylsl(), needs.guard.of("lsl"))
