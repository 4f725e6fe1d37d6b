#!/usr/bin/env python3
"""Fault soak against ground truth: a week of ordinary faults in an hour. Run by hand:

    python bench/faultsoak.py --minutes 60 --seed 1
    python bench/faultsoak.py --minutes 60 --seed 2 --model fifo
    python bench/faultsoak.py --minutes 3 --seed 1 --kinds stall unplug   # a few kinds

gx2-sim runs in this process on a pty (three nodes streaming accel_angrate at about
70% of the 115200-baud line, rates a little apart, crystals tens of ppm off); the
installed gx2-gateway runs as a subprocess on it. A subscriber keeps every record;
a tap on what the simulator writes into the pty gives each timed record its true
sample instant (the simulator's ``sampled``, read as the packet is written, so a
node's restarted timer never meets an old reading). Status is polled at 2 Hz over the
control socket, never blocking the loop.

A seeded schedule of ordinary faults, one at a time, each followed by its recovery
and some quiet time (every kind in turn, in a shuffled order, so that a short run
covers them evenly):

- ``stall``: the gateway's process stopped (SIGSTOP) for 0.3-3 s, then SIGCONT;
- ``cpu``: two busy processes (both cores) for 5-20 s;
- ``unplug``: the base station unplugged for 0.5-5 s, then plugged back in;
- ``power_one`` / ``power_all``: one node, or every node, off for 0.5-5 s, then on;
- ``radio``: one node's (or every node's) radio loss raised to 20-100% for 3-15 s;
- ``load``: the line's load moved to 50-98% for 10-30 s (node 76's rate, by the
  gateway's ``rate`` op), then back;
- ``overload``: 110-140% of the line for 10-60 s (node 76 streaming
  accel_angrate_orientation at a faster rate, by ``start`` and ``rate``), then back;
- ``reload``: node 77's name changed in the configuration, then SIGHUP;
- ``mqtt``: the MQTT broker (mosquitto, the gateway's ``mqtt`` output) stopped for
  2-15 s, then started again on its port;
- ``disk``: the recording's disk (a tmpfs of 16 MiB of its own, tests/helpers/
  smalldisk.py, root only) filled to ENOSPC for 3-15 s, then freed.

With ``mqtt`` or ``disk`` among the kinds, the gateway publishes to mosquitto or
records (1 MB files, 6 MB kept) throughout, as a deployment does.

Two models of the base station (``--model``): ``gx2sim``, gx2-sim's own (a 4 KiB
output buffer that drops when full, the line at its baud rate), and ``fifo``, a FIFO
base station as bench/linequeue.py's, behind the same pty: a gap after each packet, so
that a saturated line reads at 90.6% of its baud rate, and a buffer of 16 KiB (1.6 s
of that line) that queues what the line cannot carry. The loads and overloads are
shares of what that line carries (node 76 at 1 Hz at least).

Checked at the end, from the records, the truth and the polls:

- recovery: from each fault's end to the first status (asked after the end) with the
  gateway and every node OK and every clock locked; bound: ``health.window_s`` (a
  fault's losses and reboots stay in the health window that long, by design) plus
  RECOVERY_SLACK;
- ``time`` - truth, per node against its median outside the windows (a window: a
  fault and its recovery, the warm-up, and the polls around one where status says the
  node's clock is held, unlocked or its floor unseen): p99 of |error - median| and the
  spread of the nodes' medians, inside and outside; targets outside: p99 <= 0.2 ms,
  medians within 0.15 ms;
- honesty: the share of samples more than 0.5 ms off whose arrival had, within 1 s, a
  status naming the node's clock or line in a WARN (target >= 95%); the share of such
  WARN time (poll to poll) whose samples, those within the same 1 s of it, were all
  within 0.2 ms (target <= 5%; the share counting only the samples between the two
  polls is shown too: a power-up's bad samples come in its first 0.2 s, before a 2 Hz
  poll can see its WARN, so that share calls most such WARNs needless); every
  ``clock.late_ms`` given at least the true lateness (less the node's median error) of
  the node's samples arriving around that poll, within LATE_TOLERANCE;
- losses: the replies delivered into the pty, received, published and got (the
  tap of bench/soak.py); nothing may be lost in the gateway;
- the recording (with ``disk``): every record got is in the files (read by the
  ``mcap`` package's reader as each is finished, before retention deletes it), but
  those got within a full disk's window (from TAKEN_BACK_S before it filled to its
  recovery) and before the first file read;
- the gateway's RSS (each minute) and open descriptors: no growth over the run's
  second half (soakreport.RSS_FLAT_KIB), no descriptor more at the end.

The exit status is 1 if an invariant fails.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import pickle
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from array import array
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import orjson
import yaml
import zmq
from benchutil import (
    Tap,
    Watcher,
    free_port,
    gateway_command,
    gateway_losses,
    open_fds,
    rss_kib,
    unix_minus_monotonic,
)
from mcap.reader import NonSeekingReader
from soakrecords import ADDRESSES, NODES, RECOVERY_SLACK, Fault, NodePoll, Poll, Result, Samples
from soakreport import analyse, print_report

from aspp import Reply
from aspp.frame import REPLY_OVERHEAD
from aspp.records import BY_NAME, lookup
from gateway.common.topics import parse
from gateway.daemon.outputs.recorder import FLUSH_S, WAKE_S
from gateway.sim.base_station import RADIO_LATENCY, BaseStation, LineFaults
from gateway.sim.node import NodeSettings
from gateway.sim.server import Simulator
from tests.helpers.broker import MOSQUITTO, Broker
from tests.helpers.smalldisk import SmallDisk, Unavailable

STREAM, BIG_STREAM = "accel_angrate", "accel_angrate_orientation"
LINE_BYTES = 11520.0
"""Bytes a second a 115200-baud line carries."""
KINDS = ("stall", "cpu", "unplug", "power_one", "power_all", "radio", "load", "overload",
         "reload", "mqtt", "disk")
MODELS: dict[str, LineFaults] = {
    "gx2sim": LineFaults(),
    "fifo": LineFaults(buffer_bytes=16384, throughput=0.906)}
"""The base station's output, by ``--model``."""
DISK = "size=16m"
TAKEN_BACK_S = 2 * FLUSH_S + WAKE_S
"""Seconds before a disk fills whose records a file cut short loses: back to its last
flush (gateway.daemon.outputs.recorder, due FLUSH_S after the flush and retention
before it ended), and those the thread had not yet taken."""
RSS_PERIOD = 60.0
"""Seconds between readings of the gateway's RSS (whether it grows, or settles)."""
HARVEST_PERIOD = 5.0
"""Seconds between reads of the recording's finished files (retention keeps each one
for minutes)."""
RECORD = {"rotate_mb": 1.0, "keep_gb": 0.006}
POLL_PERIOD = 0.5
UNMATCHED_S = 2.0
"""Seconds a record waits for the tap to decode its packet (the simulator's thread may
be descheduled between writing a packet and decoding it; the gateway may not)."""



def bytes_per_second(stream: str, hz: float) -> float:
    return (BY_NAME[stream].reply_size + REPLY_OVERHEAD) * hz


def rate_hz(node: NodeSettings) -> float:
    return 51200 / node.divider


def others_load() -> float:
    """Bytes a second nodes 77 and 78 send: what node 76's rate is set against."""
    return sum(bytes_per_second(STREAM, rate_hz(n)) for n in NODES[1:])


def node76_hz(rig: Rig, share: float, stream: str) -> float:
    """Node 76's rate that makes the line carry ``share`` of what it can (1 Hz at
    least: the others alone may carry more on the FIFO line)."""
    return max(1.0, (share * LINE_BYTES * rig.line.throughput - others_load())
               / bytes_per_second(stream, 1.0))


# -- the rig: simulator, gateway, subscriber ----------------------------------------


class Truths:
    """Each timed record's true instant, taken from the simulator as the tap sees its
    packet written (its timer then is the one the node sampled it at)."""

    def __init__(self, sim: Simulator) -> None:
        self.sim = sim
        self.lock = threading.Lock()
        self.by_timer: dict[tuple[int, int], float] = {}

    def on_reply(self, reply: Reply, _now: float) -> None:
        spec = lookup(reply.command) if reply.command in TIMED else None
        node = self.sim.station.nodes.get(reply.node)
        if spec is None or node is None:
            return
        timer = int.from_bytes(reply.payload[-4:], "big")
        truth = node.sampled.get(timer)
        if truth is not None:
            with self.lock:
                self.by_timer[(reply.node, timer)] = truth
                if len(self.by_timer) > 200_000:  # (records lost at an unplug)
                    del self.by_timer[next(iter(self.by_timer))]

    def take(self, node: int, timer: int) -> float | None:
        with self.lock:
            return self.by_timer.pop((node, timer), None)

    def forget(self, addresses: Iterable[int]) -> None:
        """The nodes powered off: their timers start again, and a reading of the new
        power-up must not be matched to a packet of the old one that was never read
        (one such match read 173 s off)."""
        with self.lock:
            for key in [k for k in self.by_timer if k[0] in addresses]:
                del self.by_timer[key]


TIMED = frozenset(spec.code for spec in BY_NAME.values() if spec.timed)


class Rig:
    """gx2-sim on a pty, the installed gateway on it, and a watcher of both."""

    def __init__(self, seed: int, window_s: float, settle_s: float, model: str,
                 kinds: tuple[str, ...]) -> None:
        self.work = Path(tempfile.mkdtemp(prefix="gx2-faultsoak-"))
        self.link = self.work / "gx2"
        self.line = MODELS[model]
        with contextlib.ExitStack() as undo:  # (what started, stopped if the rest fails)
            undo.callback(shutil.rmtree, self.work, ignore_errors=True)
            self.disk = SmallDisk(self.work, DISK) if "disk" in kinds else None
            if self.disk is not None:
                undo.callback(self.disk.close)
            self.broker = Broker(self.work) if "mqtt" in kinds else None
            if self.broker is not None:
                undo.callback(self.broker.stop)
            self.sim = Simulator(list(NODES), link=self.link, seed=seed, line=self.line).start()
            undo.callback(self.sim.stop)
            self.truths = Truths(self.sim)
            self.tap = Tap(self.sim, self.truths.on_reply)
            self.samples = Samples()
            self.shift = unix_minus_monotonic()
            self.config = self.work / "nodes.yaml"
            publish, control = (f"tcp://127.0.0.1:{free_port()}" for _ in range(2))
            self.settings: dict[str, Any] = {
                "base_station": {"port": str(self.link), "latency_ms": RADIO_LATENCY * 1000},
                "publish": {"endpoint": publish},
                "control": {"endpoint": control, "allow_eeprom_write": True},
                "health": {"window_s": window_s, "settle_s": settle_s},
                "nodes": [{"address": a, "stream": STREAM, "name": f"n{a}"}
                          for a in ADDRESSES]}
            if self.broker is not None:
                self.settings["mqtt"] = {"url": self.broker.url}
            command = [gateway_command(), "--config", str(self.config), "--log-level", "INFO"]
            if self.disk is not None:
                self.settings["record"] = {
                    "directory": str(self.disk.inside / "recordings"), **RECORD}
                # (nsenter, not a preexec_fn: the simulator's thread is running)
                command = ["nsenter", f"--mount={self.disk.namespace}", "--", *command]
            self.write_config()
            self.log = (self.work / "gateway.log").open("w")
            undo.callback(self.log.close)
            self.gateway = subprocess.Popen(command, stdout=self.log, stderr=subprocess.STDOUT)
            undo.callback(self.stop_gateway)
            self.context = zmq.Context()
            undo.callback(self.context.destroy, linger=0)
            self.watch = Watcher(self.context, publish, control, self.on_record)
            undo.pop_all()
        self.hogs: list[subprocess.Popen[bytes]] = []
        self.unmatched: list[tuple[float, int, int, float]] = []
        """(arrival, node, timer, time on the monotonic clock) awaiting their truth."""
        self.got = Keys()
        """Every record got, for the recording's check (with ``disk`` only)."""
        self.recorded = Recorded()

    def write_config(self) -> None:
        self.config.write_text(yaml.safe_dump(self.settings))

    def on_record(self, _topic: bytes, message: dict[str, Any]) -> None:
        if self.disk is not None and "seq" in message:
            self.got.add(message, time.monotonic())
        if "time" not in message or "timer" not in message:
            return
        node = message["node"]
        truth = self.truths.take(node, message["timer"])
        if node not in self.samples.truth:
            return
        unix = message["time"] - self.shift
        if truth is None:  # (the tap may not have decoded what it wrote yet)
            self.unmatched.append((time.monotonic(), node, message["timer"], unix))
            return
        self.samples.add(node, truth, time.monotonic(), unix - truth)

    def match_late(self, now: float) -> None:
        """Records that arrived before the tap had decoded their packet: matched now,
        or counted as without truth after UNMATCHED_S."""
        waiting, self.unmatched = self.unmatched, []
        for arrival, node, timer, unix in waiting:
            truth = self.truths.take(node, timer)
            if truth is not None:
                self.samples.add(node, truth, arrival, unix - truth)
            elif now - arrival < UNMATCHED_S:
                self.unmatched.append((arrival, node, timer, unix))
            else:
                self.samples.untrue += 1

    def stop_gateway(self) -> None:
        """SIGTERM (after SIGCONT: it may be stopped), as systemd stops it."""
        if self.gateway.poll() is None:
            self.gateway.send_signal(signal.SIGCONT)
            self.gateway.terminate()
            try:
                self.gateway.wait(10)
            except subprocess.TimeoutExpired:
                self.gateway.kill()
                self.gateway.wait()

    def harvest(self, everything: bool = False) -> None:
        """Read the recording's finished files not read yet (every file, once the
        gateway has stopped)."""
        assert self.disk is not None
        paths = sorted((self.disk.outside / "recordings").glob("*.mcap"))
        self.recorded.read(paths if everything else paths[:-1])

    def close(self) -> None:
        """Everything started, stopped (each whatever the others do)."""
        with contextlib.ExitStack() as stack:
            if self.disk is not None:
                stack.callback(self.disk.close)
            if self.broker is not None:
                stack.callback(self.broker.stop)
            stack.callback(self.log.close)
            stack.callback(self.context.destroy, linger=0)
            stack.callback(self.sim.stop)
            stack.callback(self.stop_gateway)
            for hog in self.hogs:
                stack.callback(hog.wait)
                stack.callback(hog.kill)


class Keys:
    """Records as (node, seq, host_time) hashed, with their arrival: an hour's are some
    900,000 (16 bytes each here, not a tuple's 100)."""

    def __init__(self) -> None:
        self.hashes = array("q")
        self.arrivals = array("d")

    def add(self, message: dict[str, Any], arrival: float) -> None:
        self.hashes.append(hash((message["node"], message["seq"], message["host_time"])))
        self.arrivals.append(arrival)


class Recorded:
    """The records of the recording's files read so far, and the files that could not
    be read to their end (a file cut short by a full disk may lack its end: read up to
    where it stops, as every reader of a recording does)."""

    def __init__(self) -> None:
        self.hashes: set[int] = set()
        self.first: float | None = None
        """Host time of the first record read."""
        self.done: set[str] = set()
        self.cut: list[str] = []

    def read(self, paths: list[Path]) -> None:
        """Each file once: a finished one (the recorder finishes a file before it
        begins the next, so every file but the newest is), or any once the gateway has
        stopped."""
        for path in paths:
            if path.name in self.done:
                continue
            self.done.add(path.name)
            try:
                with path.open("rb") as stream:
                    # (in the file's order: in log time order the reader sorts the whole
                    # file first, and a file cut short gave none of its records)
                    messages = NonSeekingReader(stream).iter_messages(log_time_order=False)
                    for _, channel, message in messages:
                        if parse(channel.topic) is not None:  # (a node's record)
                            record = orjson.loads(message.data)
                            self.hashes.add(hash((record["node"], record["seq"],
                                                  record["host_time"])))
                            if self.first is None:
                                self.first = record["host_time"]
            except FileNotFoundError:  # (retention was first)
                continue
            except Exception as error:  # (mcap's errors have no common base)
                self.cut.append(f"{path.name}: {type(error).__name__} {error}")


# -- the faults -----------------------------------------------------------------------

Begin = Callable[[Rig, random.Random], tuple[float, str, Callable[[], None] | None]]
"""Starts a fault; returns its duration, what it is, and what ends it (None: nothing)."""


def stall(rig: Rig, rng: random.Random) -> tuple[float, str, Callable[[], None]]:
    seconds = rng.uniform(0.3, 3.0)
    rig.gateway.send_signal(signal.SIGSTOP)
    return seconds, f"{seconds:.2f} s", lambda: rig.gateway.send_signal(signal.SIGCONT)


def cpu(rig: Rig, rng: random.Random) -> tuple[float, str, Callable[[], None]]:
    seconds = rng.uniform(5.0, 20.0)
    rig.hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
                for _ in range(2)]

    def undo() -> None:
        for hog in rig.hogs:
            hog.kill()
            hog.wait()
        rig.hogs = []
    return seconds, f"{seconds:.1f} s, 2 hogs", undo


def unplug(rig: Rig, rng: random.Random) -> tuple[float, str, Callable[[], None]]:
    seconds = rng.uniform(0.5, 5.0)
    rig.sim.unplug()
    return seconds, f"{seconds:.1f} s", rig.sim.replug


def power(addresses: tuple[int, ...]) -> Begin:
    def begin(rig: Rig, rng: random.Random) -> tuple[float, str, Callable[[], None]]:
        seconds = rng.uniform(0.5, 5.0)
        for a in addresses:
            rig.sim.power(a, False)

        def undo() -> None:
            rig.truths.forget(addresses)
            for a in addresses:
                rig.sim.power(a, True)
        return seconds, f"{','.join(map(str, addresses))} off {seconds:.1f} s", undo
    return begin


def radio(rig: Rig, rng: random.Random) -> tuple[float, str, Callable[[], None]]:
    seconds, loss = rng.uniform(3.0, 15.0), rng.choice([0.2, 0.5, 0.8, 1.0])
    addresses = ADDRESSES if rng.random() < 0.3 else (rng.choice(ADDRESSES),)

    def set_loss(value: float) -> Callable[[BaseStation, float], None]:
        def change(station: BaseStation, _now: float) -> None:
            for a in addresses:
                station.radio[a].data_loss = station.radio[a].command_loss = value
        return change
    rig.sim.call(set_loss(loss))
    return (seconds, f"{','.join(map(str, addresses))} {loss:.0%} for {seconds:.1f} s",
            lambda: rig.sim.call(set_loss(0.0)))


def node76(rig: Rig, stream: str, hz: float) -> None:
    """Node 76 to ``stream`` at ``hz``, through the gateway as an operator would."""
    rig.watch.ask("rate", node=76, hz=hz, timeout=10.0)
    rig.watch.ask("start", node=76, record=stream, timeout=10.0)


def restore76(rig: Rig) -> Callable[[], None]:
    return lambda: node76(rig, STREAM, rate_hz(NODES[0]))


def load(rig: Rig, rng: random.Random) -> tuple[float, str, Callable[[], None]]:
    seconds, share = rng.uniform(10.0, 30.0), rng.uniform(0.50, 0.98)
    hz = node76_hz(rig, share, STREAM)
    node76(rig, STREAM, hz)
    return seconds, f"{share:.0%} ({hz:.1f} Hz) for {seconds:.0f} s", restore76(rig)


def overload(rig: Rig, rng: random.Random) -> tuple[float, str, Callable[[], None]]:
    seconds, share = rng.uniform(10.0, 60.0), rng.uniform(1.10, 1.40)
    hz = node76_hz(rig, share, BIG_STREAM)
    node76(rig, BIG_STREAM, hz)
    return seconds, f"{share:.0%} ({BIG_STREAM} {hz:.1f} Hz) for {seconds:.0f} s", \
        restore76(rig)


def reload(rig: Rig, _rng: random.Random) -> tuple[float, str, None]:
    node = rig.settings["nodes"][1]
    node["name"] = "m77" if node["name"] == "n77" else "n77"
    rig.write_config()
    rig.gateway.send_signal(signal.SIGHUP)
    return 0.0, f"node 77 named {node['name']}, SIGHUP", None


def mqtt(rig: Rig, rng: random.Random) -> tuple[float, str, Callable[[], None]]:
    assert rig.broker is not None
    seconds = rng.uniform(2.0, 15.0)
    rig.broker.stop()
    return seconds, f"broker stopped {seconds:.1f} s", rig.broker.start


def disk(rig: Rig, rng: random.Random) -> tuple[float, str, Callable[[], None]]:
    assert rig.disk is not None
    seconds = rng.uniform(3.0, 15.0)
    rig.disk.fill()
    return seconds, f"full {seconds:.1f} s", rig.disk.free


BEGIN: dict[str, Begin] = {
    "stall": stall, "cpu": cpu, "unplug": unplug, "power_one": power((77,)),
    "power_all": power(ADDRESSES), "radio": radio, "load": load, "overload": overload,
    "reload": reload, "mqtt": mqtt, "disk": disk}


def deck(rng: random.Random, kinds: tuple[str, ...]) -> Iterable[str]:
    """Every kind in turn, each round shuffled: a short run still covers them all."""
    while True:
        order = list(kinds)
        rng.shuffle(order)
        yield from order


# -- the loop -------------------------------------------------------------------------


def node_poll(node: dict[str, Any]) -> NodePoll:
    clock = node.get("clock") or {}
    return NodePoll(node["health"], tuple(node.get("reasons") or ()),
                    bool(clock.get("locked")), clock.get("floor_age_s"),
                    clock.get("floor_seen"), clock.get("late_ms"))


def make_poll(asked: float, status: dict[str, Any]) -> Poll:
    nodes = {n["node"]: node_poll(n) for n in status["nodes"]}
    gateway = status["gateway"]
    mqtt = status.get("mqtt") or {}
    healthy = gateway["health"] == "OK" and mqtt.get("connected", True) and all(
        nodes.get(a) is not None and nodes[a].health == "OK" and nodes[a].locked
        for a in ADDRESSES)
    return Poll(asked, time.monotonic(), healthy, nodes, tuple(gateway.get("reasons") or ()))


class Poller:
    """Asks for status every POLL_PERIOD, one request at a time (given up after 5 s:
    a stopped gateway answers it when it runs again, and that answer is still taken)."""

    def __init__(self, watch: Watcher) -> None:
        self.watch = watch
        self.polls: list[Poll] = []
        self.pending: dict[str, float] = {}
        self.next_at = 0.0
        self.ops_failed: list[str] = []

    def tick(self, now: float) -> None:
        for request_id, reply in list(self.watch.answers.items()):
            del self.watch.answers[request_id]
            asked = self.pending.pop(request_id, None)
            if asked is not None and reply.get("ok"):
                self.polls.append(make_poll(asked, reply["result"]))
            elif asked is None and not reply.get("ok"):  # an operator's op of a fault
                self.ops_failed.append(f"{reply.get('error')}: {reply.get('message')}")
        if now >= self.next_at and all(now - t > 5.0 for t in self.pending.values()):
            self.pending[self.watch.ask("status", timeout=5.0)] = now
            self.next_at = now + POLL_PERIOD

    def healthy_since(self, since: float) -> Poll | None:
        """The first healthy poll asked after ``since``."""
        i = len(self.polls)
        while i > 0 and self.polls[i - 1].asked > since:
            i -= 1
        return next((p for p in self.polls[i:] if p.healthy), None)


@dataclass
class Schedule:
    """Faults one at a time: begin, end when due, wait for recovery (or the bound),
    then quiet time; nothing new begins within ``last_start`` of the run's end."""

    rig: Rig
    poller: Poller
    rng: random.Random
    kinds: Iterable[str]
    bound: float
    quiet: tuple[float, float]
    faults: list[Fault] = field(default_factory=list)
    next_start: float = 0.0
    rig_start: float = 0.0
    active: Fault | None = None

    def tick(self, now: float, may_begin: bool) -> None:
        fault = self.active
        if fault is None:
            if may_begin and now >= self.next_start:
                self.begin(now)
            return
        if fault.end is None:
            if now >= fault.due:
                if fault.undo is not None:
                    fault.undo()
                fault.end = time.monotonic()
            return
        poll = self.poller.healthy_since(fault.end)
        if poll is not None or now > fault.end + self.bound:
            if poll is not None:
                fault.recovered = poll.at - fault.end
            self.active = None
            self.next_start = now + self.rng.uniform(*self.quiet)

    def begin(self, now: float) -> None:
        kind = next(iter(self.kinds))
        seconds, detail, undo = BEGIN[kind](self.rig, self.rng)
        fault = Fault(kind, detail, now, now + seconds, undo=undo)
        self.faults.append(fault)
        self.active = fault
        print(f"  {now - self.rig_start:7.1f} s  {kind:<9} {detail}", flush=True)


def warm_up(rig: Rig, poller: Poller, settle_s: float, limit: float = 60.0) -> float:
    """Until the first healthy status (every node streaming, OK and locked) asked once
    the streams are old enough to be judged (settle_s after the start, and 2 s more)."""
    start = time.monotonic()
    deadline = start + limit
    while (now := time.monotonic()) < deadline:
        rig.watch.drain(0.05)
        rig.match_late(now)
        poller.tick(now)
        if poller.healthy_since(start + settle_s + 2.0) is not None:
            return now
        if rig.gateway.poll() is not None:
            raise RuntimeError(f"the gateway exited; its log: {rig.work / 'gateway.log'}")
    raise RuntimeError(f"not healthy within {limit:.0f} s; its log: {rig.work / 'gateway.log'}")


def stop_and_settle(rig: Rig, poller: Poller) -> dict[str, Any] | None:
    """Stop the streams as gx2ctl stop does, then wait until the counts settle."""
    poller.tick(time.monotonic())  # (take what answers are waiting)
    for address in ADDRESSES:
        rig.watch.request("stop", node=address)
    settle = time.monotonic() + 10
    status = rig.watch.status()
    while time.monotonic() < settle:
        rig.watch.drain(0.5)
        status = rig.watch.status()
        if status and sum(n["published"] for n in status["nodes"]) == sum(
                rig.watch.received.values()):
            break
    return status


def recording_check(rig: Rig, faults: list[Fault], bound: float) -> tuple[int, int, int]:
    """(records checked, of them missing from the recording, got within a full disk's
    window and not checked): every record got from the first the files hold."""
    rig.harvest(everything=True)
    recorded = rig.recorded
    if recorded.first is None:
        return 0, 0, 0
    first = recorded.first - rig.shift  # (host_time on the monotonic clock, roughly)
    full = [(f.start - TAKEN_BACK_S,
             (f.end or f.due) + (f.recovered if f.recovered is not None else bound))
            for f in faults if f.kind == "disk"]
    checked = missing = skipped = 0
    for key, arrival in zip(rig.got.hashes, rig.got.arrivals, strict=True):
        if arrival < first + 1.0:  # (got before the recorder's first record: not checked)
            continue
        if any(start <= arrival <= end for start, end in full):
            skipped += 1
            continue
        checked += 1
        missing += key not in recorded.hashes
    return checked, missing, skipped


def run(seconds: float, seed: int, *, kinds: tuple[str, ...] = KINDS, window_s: float = 20.0,
        settle_s: float = 5.0, quiet: tuple[float, float] = (5.0, 20.0),
        keep: bool = False, model: str = "gx2sim") -> Result:
    """The soak: warm-up, then faults for ``seconds``, then the final counts."""
    rng = random.Random(seed)
    rig = Rig(seed, window_s, settle_s, model, kinds)
    poller = Poller(rig.watch)
    next_harvest = 0.0
    try:
        started = time.monotonic()
        warmed = warm_up(rig, poller, settle_s)
        resources = [(rss_kib(rig.gateway.pid), open_fds(rig.gateway.pid))]
        rss = [(0.0, resources[0][0])]
        next_rss = warmed + RSS_PERIOD
        schedule = Schedule(rig, poller, rng, deck(rng, kinds), window_s + RECOVERY_SLACK,
                            quiet, next_start=warmed + rng.uniform(*quiet) / 2)
        schedule.rig_start = started
        end = warmed + seconds
        longest = 60.0 + window_s + RECOVERY_SLACK
        next_shift = 0.0
        while (now := time.monotonic()) < end or schedule.active is not None:
            rig.watch.drain(0.05)
            rig.match_late(now)
            poller.tick(now)
            schedule.tick(now, may_begin=end - now > min(longest, seconds / 4))
            if now >= next_shift:
                rig.shift, next_shift = unix_minus_monotonic(), now + 1.0
            if now >= next_rss:
                rss.append((now - warmed, rss_kib(rig.gateway.pid)))
                next_rss += RSS_PERIOD
            if rig.disk is not None and now >= next_harvest:
                rig.harvest()
                next_harvest = now + HARVEST_PERIOD
            if rig.gateway.poll() is not None:
                raise RuntimeError(f"the gateway exited; its log: {rig.work / 'gateway.log'}")
        status = stop_and_settle(rig, poller)
        resources.append((rss_kib(rig.gateway.pid), open_fds(rig.gateway.pid)))
        if status is None:
            raise RuntimeError("the gateway stopped answering")
        losses = gateway_losses(status, rig.tap, rig.watch, ADDRESSES)
        rig.stop_gateway()
        recording = recording_check(rig, schedule.faults, schedule.bound) \
            if rig.disk is not None else None
    finally:
        rig.close()
    if not keep:
        shutil.rmtree(rig.work, ignore_errors=True)
    rig.samples.sort()
    return Result(seconds, window_s, started, warmed, schedule.faults, poller.polls,
                  rig.samples, losses, resources, poller.ops_failed, rig.work, model,
                  recording, rig.recorded.cut, rss)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=60.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--kinds", nargs="+", choices=KINDS, default=list(KINDS))
    parser.add_argument("--model", choices=tuple(MODELS), default="gx2sim",
                        help="the base station's output (the module's docstring)")
    parser.add_argument("--health-window", type=float, default=20.0,
                        help="the gateway's health.window_s (the recovery bound's base)")
    parser.add_argument("--keep", action="store_true", help="keep the work directory")
    parser.add_argument("--save", type=Path, help="pickle the run here (for --load)")
    parser.add_argument("--load", type=Path, help="analyse a run saved with --save")
    parser.add_argument("--unwarned", type=int, default=10,
                        help="how many off samples with no WARN to list")
    args = parser.parse_args()
    # (SIGTERM ends the run as Ctrl-C does: the gateway, broker and disk stopped)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    if "mqtt" in args.kinds and MOSQUITTO is None:
        parser.exit(2, "faultsoak: the mqtt fault needs mosquitto (apt install "
                       "mosquitto); or leave it out of --kinds\n")
    if args.load:
        result = pickle.loads(args.load.read_bytes())
    else:
        print(f"fault soak: {args.minutes:g} min, seed {args.seed}, model {args.model}, "
              f"pid {os.getpid()}", flush=True)
        try:
            result = run(args.minutes * 60, args.seed, kinds=tuple(args.kinds),
                         window_s=args.health_window, keep=args.keep, model=args.model)
        except Unavailable as why:
            parser.exit(2, f"faultsoak: the disk fault needs {why}; or leave it out of "
                           "--kinds\n")
        if args.save:
            for fault in result.faults:
                fault.undo = None  # (a closure over the run's processes)
            args.save.write_bytes(pickle.dumps(result))
    report = analyse(result, listed=args.unwarned)
    print_report(result, report)
    if args.keep:
        print(f"work directory (gateway.log): {result.work}")
    return 0 if report.passed else 1


if __name__ == "__main__":
    sys.exit(main())
