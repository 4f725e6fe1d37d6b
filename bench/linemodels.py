"""Serial lines in simulated time, and the gateway's clock path fed from them: what the
sample-time sweep (bench/sweep.py), bench/timesync.py --model and the suite's
regression seeds (tests/aspp/test_clock_sweep.py) share.

A line model is a list of :class:`Packet` s in the order the host reads them: when the
read that held a packet's last byte was made, the packet's timer reading and size, and
the instant its sample was really taken (plus the run's radio floor, which no host can
see and the gateway's ``latency_ms`` stands for). Two models, written apart:

- :func:`gx2sim_packets`: gx2-sim's own base station and nodes (gateway.sim), advanced
  event by event, every packet read the moment its last byte leaves the UART.
- :func:`fifo_packets`: a FIFO UART written here from the line's description alone: the
  packets of every node queue in the order they reach the base station and drain at
  115200 baud; radio delays from several distributions; the host's reads at the USB's
  frames and paused for tens to hundreds of ms at random; crystals within +-50 ppm,
  power-up phases at random, reboots and timer wraps.

:func:`feed` then does to each packet what gateway.daemon.station.nodes.Node.tally does for the
clock: the arrival is the read's instant less the packet's own bytes on the line, the
timer is unwrapped by a TimerUnwrapper judging by the node's NodeClock, a restarted
timer (or a discovery packet) resets the clock, and ``time`` is the clock's line at the
device time. :func:`measure` gives a run's figures.
"""

from __future__ import annotations

import math
import random
import statistics
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import NamedTuple

from aspp import Decoder, Frame, Reply, decode
from aspp.clock import NodeClock

try:
    from aspp.clock import waited
except ImportError:  # (a tree from before the floor's sighting took the line's waits)
    waited = None  # type: ignore[assignment]
try:
    from aspp.refine import refine
except ImportError:  # (a tree from before the time placed after the fact)
    refine = None  # type: ignore[assignment]
from aspp.frame import HEADER_SIZE, REPLY_OVERHEAD
from aspp.records import BY_NAME
from aspp.timing import (
    CLOCK_HZ,
    TICKS_PER_CLOCK,
    TICKS_PER_SECOND,
    TIMER_MODULUS,
    TimerUnwrapper,
    byte_time,
    sample_period,
)

try:
    from gateway.daemon.station.nodes import SILENCE_PERIODS
except ImportError:  # (a tree from before the daemon's station/ package, measured against)
    from gateway.daemon.nodes import SILENCE_PERIODS  # type: ignore[no-redef]
from gateway.sim.base_station import RADIO_LATENCY, BaseStation, LineFaults
from gateway.sim.node import NodeSettings, SimNode

BAUD = 115200
BYTE_TIME = byte_time(BAUD)
WARM_UP = 5.0
"""Seconds of each stream (its start, and after a reboot) left out of the figures."""
MINUTE = 60.0
DRIFT_BIN = 5.0
"""Seconds of a stream whose median error is one point of its error's drift."""


class Packet(NamedTuple):
    """One packet as the host reads it. ``ticks`` None: a discovery packet (the node
    announced a power-up)."""

    read: float
    """Host seconds of the read that held its last byte."""
    node: int
    ticks: int | None
    size: int
    """Bytes on the line."""
    truth: float
    """Host seconds its sample was taken, plus the run's radio floor."""
    segment: int
    """The node's power-up: 0, then 1 after a reboot."""


@dataclass
class Model:
    """A run of a line model: its packets, the nodes' sample periods, and what it was."""

    packets: list[Packet]
    periods: dict[int, float]
    load: float
    """Share of the line's bytes the nodes' streams take."""
    about: str


# -- the gateway's clock path ---------------------------------------------------------------


VISIBLE_BIN = 10.0
"""Seconds of a stream in each of which its floor must show for the run to count as one
the host could place (where every stream's did, the estimate holds the targets on
gx2-sim's line: docs/performance-history.md)."""
VISIBLE_WITHIN = 0.1e-3
"""A packet shows its floor to the host when it did not wait behind another on the line
and began there within this of its sample's instant plus the radio's floor."""
try:
    from gateway.daemon.config import FLOOR_UNSEEN_S
except ImportError:  # (a tree from before the floor's age)
    FLOOR_UNSEEN_S = 30.0


@dataclass
class Streams:
    """Per (node, segment): (true instant, error of ``time``) after WARM_UP; each
    stream's share of packets that began on the line as the one before ended; the share
    of its VISIBLE_BINs in which a packet showed the host its floor (a stream under 1
    gives the host stretches of 10 s or more with nothing that places its samples); and
    its clock's floor age at each packet after WARM_UP (None: not locked)."""

    errors: dict[tuple[int, int], list[tuple[float, float]]] = field(default_factory=dict)
    queued: dict[tuple[int, int], float] = field(default_factory=dict)
    visible: dict[tuple[int, int], float] = field(default_factory=dict)
    ages: dict[tuple[int, int], list[float | None]] = field(default_factory=dict)
    bounds: dict[tuple[int, int], list[float | None]] = field(default_factory=dict)
    """The bound status gives at each packet after WARM_UP (``late_ms``, seconds): None
    unless the floor went FLOOR_UNSEEN_S unseen after it was seen."""
    refined: dict[tuple[int, int], list[tuple[float, float, float | None]]] = field(
        default_factory=dict)
    """Per stream, after WARM_UP: (true instant, error of the time placed after the fact
    from the whole run, aspp.refine, and its bound; None: unplaceable or live)."""


def feed(model: Model, clock: type[NodeClock] = NodeClock) -> Streams:
    """Each packet through the clock path of gateway.daemon.station.nodes.Node.tally."""
    clocks: dict[int, NodeClock] = {}
    unwrappers: dict[int, TimerUnwrapper] = {}
    for node, period in model.periods.items():
        clocks[node] = clock()
        unwrappers[node] = TimerUnwrapper(expect=clocks[node].device_at,
                                          late_step=SILENCE_PERIODS * period)
    out = Streams()
    starts: dict[tuple[int, int], float] = {}
    counts: dict[tuple[int, int], list[int]] = {}
    shown: dict[tuple[int, int], dict[int, bool]] = {}
    line_free = -math.inf
    series: dict[tuple[int, int], list[tuple[float, float, bool, float, float]]] = {}
    for packet in model.packets:
        node = packet.node
        arrival = packet.read - packet.size * BYTE_TIME
        queued = arrival - line_free < BYTE_TIME
        behind = waited is not None and waited(arrival, line_free)  # (the host's margin)
        line_free = packet.read
        if packet.ticks is None:
            clocks[node].reset()
            unwrappers[node].expect_reset()
            continue
        unwrapper = unwrappers[node]
        device = unwrapper.update(packet.ticks, arrival)
        if unwrapper.last_was_reset:
            clocks[node].reset()
        time = clocks[node].update(device, arrival, behind) if behind \
            else clocks[node].update(device, arrival)
        key = (node, packet.segment)
        series.setdefault(key, []).append((device, arrival, behind, packet.truth, time))
        start = starts.setdefault(key, packet.truth)
        tally = counts.setdefault(key, [0, 0])
        tally[0] += 1
        tally[1] += queued
        bins = shown.setdefault(key, {})
        at = int((packet.truth - start) // VISIBLE_BIN)
        bins[at] = bins.get(at, False) or (not queued
                                           and arrival - packet.truth < VISIBLE_WITHIN)
        if packet.truth - start >= WARM_UP:
            out.errors.setdefault(key, []).append((packet.truth, time - packet.truth))
            age = getattr(clocks[node], "floor_age", None)
            out.ages.setdefault(key, []).append(age)
            given = age is not None and age >= FLOOR_UNSEEN_S and clocks[node].floor_seen
            out.bounds.setdefault(key, []).append(clocks[node].late_bound() if given else None)
    out.queued = {key: q / n for key, (n, q) in counts.items()}
    if refine is not None:
        for key, points in series.items():
            placed = refine([(d, a, w) for d, a, w, _, _ in points],
                            [t for *_, t in points])
            start = starts[key]
            out.refined[key] = [(truth, at - truth, bound)
                                for (_, _, _, truth, _), at, bound
                                in zip(points, placed.line, placed.bound, strict=True)
                                if truth - start >= WARM_UP]
    out.visible = {key: sum(bins.values()) / len(bins) for key, bins in shown.items()}
    return out


@dataclass(frozen=True)
class Figures:
    """A run's figures, in ms. ``p99``, ``worst``: of |error - the run's median error|
    over every node (bench/timesync.py's spread); ``apart``: the nodes' median errors'
    range; ``drift``: the most any stream's error (its median over DRIFT_BIN) moved
    within a minute (within its length, if shorter); ``free``: the least share, over
    the streams, of packets that found the line free (a stream with none never shows
    the host its floor: docs/gateway.md)."""

    p99: float
    worst: float
    apart: float
    drift: float
    free: float
    visible: float
    """The least share, over the streams, of VISIBLE_BINs in which its floor showed."""
    off: int
    """Samples more than OFF from the run's median error, after FLOOR_UNSEEN_S of
    each stream (before it, no age can have reached the threshold) ..."""
    off_said: int
    """... of which the clock's floor age was past FLOOR_UNSEEN_S (status said so)."""
    good: int
    """Samples within GOOD of the run's median error, after FLOOR_UNSEEN_S ..."""
    good_said: int
    """... of which the floor age was past FLOOR_UNSEEN_S all the same."""
    bounded: int = 0
    """Samples for which a bound of how late ``time`` may be was given ..."""
    bound_broken: int = 0
    """... of which ``time`` was later than that (against the run's median error)."""


OFF, GOOD = 0.5e-3, 0.2e-3


def _moved(errors: list[tuple[float, float]]) -> float:
    bins: dict[int, list[float]] = {}
    first = errors[0][0]
    for truth, error in errors:
        bins.setdefault(int((truth - first) // DRIFT_BIN), []).append(error)
    level = {b: statistics.median(e) for b, e in bins.items() if len(e) >= 5}
    if len(level) < 2:
        return 0.0
    reach = min(round(MINUTE / DRIFT_BIN), max(level) - min(level))
    return max(abs(level[b + reach] - level[b]) for b in level if b + reach in level)


def refined_streams(streams: Streams) -> Streams:
    """The same streams with the time placed after the fact in place of the live one
    (``bounds`` the refined bounds), for :func:`measure`."""
    return Streams({k: [(t, e) for t, e, _ in v] for k, v in streams.refined.items()},
                   streams.queued, streams.visible, streams.ages,
                   {k: [b for _, _, b in v] for k, v in streams.refined.items()})


def measure(streams: Streams) -> Figures:
    pooled = [e for errors in streams.errors.values() for _, e in errors]
    middle = statistics.median(pooled)
    spread = sorted(abs(e - middle) for e in pooled)
    medians = [statistics.median(e for _, e in errors) for errors in streams.errors.values()]
    said = [0, 0, 0, 0]  # off, off and said, good, good and said
    bounded = [0, 0]  # a bound given, and broken
    for key, errors in streams.errors.items():
        for (_, error), bound in zip(errors, streams.bounds.get(key, ()), strict=False):
            if bound is not None:
                bounded[0] += 1
                bounded[1] += error - middle > bound
        first = errors[0][0] - WARM_UP
        for (truth, error), age in zip(errors, streams.ages[key], strict=True):
            if truth - first < FLOOR_UNSEEN_S:
                continue
            unseen = age is not None and age >= FLOOR_UNSEEN_S
            if abs(error - middle) > OFF:
                said[0] += 1
                said[1] += unseen
            elif abs(error - middle) <= GOOD:
                said[2] += 1
                said[3] += unseen
    return Figures(spread[int(0.99 * (len(spread) - 1))] * 1e3, spread[-1] * 1e3,
                   (max(medians) - min(medians)) * 1e3,
                   max(_moved(errors) for errors in streams.errors.values()) * 1e3,
                   1 - max(streams.queued[key] for key in streams.errors),
                   min(streams.visible[key] for key in streams.errors), *said, *bounded)


# -- gx2-sim's line ---------------------------------------------------------------------------


def gx2sim_packets(seed: int, seconds: float, nodes: list[NodeSettings],
                   line: LineFaults, reboot: tuple[int, float] | None = None) -> Model:
    """gx2-sim's base station and nodes in simulated time: each packet read when its
    last byte leaves the UART. ``reboot``: (node, seconds in) it loses power."""
    rng = random.Random(seed)
    start = 1000.0
    sims = [SimNode(settings, start, random.Random(rng.random())) for settings in nodes]
    station = BaseStation(sims, line=line, rng=rng)
    decoder = Decoder()
    before: dict[int, dict[int, float]] = {}
    segment = {n.address: 0 for n in nodes}
    packets: list[Packet] = []
    now = start
    while now < start + seconds:
        # (at least a nanosecond on: a cycle due at now - RADIO_LATENCY by next_due may
        # round to just after it in advance, and the loop would stand still)
        now = max(station.next_due(now), now + 1e-9)
        if reboot is not None and now >= start + reboot[1] and reboot[0] not in before:
            before[reboot[0]] = dict(station.nodes[reboot[0]].sampled)
            station.nodes[reboot[0]].sampled.clear()
            station.reboot(reboot[0], now)
            now = station.next_due(now)
        station.advance(now)
        for event in decoder.feed(station.take_output(now)):
            if isinstance(event, Frame) and event.is_discovery:
                segment[event.node] += 1
                packets.append(Packet(now, event.node, None, len(event.raw), now, 0))
            if not isinstance(event, Reply):
                continue
            record = decode(event.raw, HEADER_SIZE, len(event.raw) - 4)
            node, timer = event.node, record.values[record.spec.field_names.index("timer")]
            sampled = station.nodes[node].sampled
            truth, seg = sampled.get(timer), segment[node]
            if truth is None or (node in before and seg == 0):
                truth, seg = before.get(node, {}).get(timer), 0
            if truth is not None:
                packets.append(Packet(now, node, timer, len(event.raw),
                                      truth + RADIO_LATENCY, seg))
    load = sum((BY_NAME[n.stream or ""].reply_size + REPLY_OVERHEAD) * BYTE_TIME
               / sample_period(n.divider) for n in nodes)
    return Model(packets, {n.address: sample_period(n.divider) for n in nodes}, load,
                 f"gx2-sim, {len(nodes)} nodes, {load:.0%} of the line")


STALL_MS = 50.0


def gx2sim_run(seed: int, seconds: float) -> Model:
    """One draw of gx2-sim's line for the sweep: 2 to 4 nodes streaming 0xC2 at one rate
    (60% of the line to 95% with the stalls' share), crystals within
    +-50 ppm, timers at random (some wrap in the run), gx2-sim's radio and 50 ms stalls
    at 0.2 to 1 a second (bench/timesync.py's: 1 at 90%), half the runs one
    node rebooted. (gx2-sim powers its nodes up together: its phases are not drawn.)"""
    rng = random.Random(f"gx2sim-{seed}")
    count = rng.randint(2, 4)
    size = BY_NAME["accel_angrate"].reply_size + REPLY_OVERHEAD
    stall_rate = rng.uniform(0.2, 1.0)
    # (gx2-sim's stalls hold the line: what they take is not the nodes', and a line
    # over 95% with them is one the gateway holds its clocks on: not this sweep's)
    most = 0.95 - stall_rate * STALL_MS / 1000
    rate = rng.uniform(0.60, most) / (count * size * BYTE_TIME)
    divider = max(170, round(CLOCK_HZ / rate))
    nodes = [NodeSettings(76 + i, divider=divider, stream="accel_angrate",
                          ppm=rng.uniform(-50, 50),
                          timer_start=rng.uniform(0, TIMER_MODULUS / TICKS_PER_SECOND))
             for i in range(count)]
    line = LineFaults(stall_rate=stall_rate, stall_ms=STALL_MS)
    reboot = (76 + rng.randrange(count), rng.uniform(0.3, 0.6) * seconds) \
        if rng.random() < 0.5 else None
    return gx2sim_packets(rng.randrange(2**32), seconds, nodes, line, reboot)


# -- a FIFO UART, written apart from gx2-sim ----------------------------------------------------

STREAMS = ("accel_angrate", "euler", "orientation", "accel_angrate_mag", "euler_angrate",
           "accel_angrate_orientation")
"""Timed records a node may stream (sizes 28 to 76 bytes with the envelope)."""


def _radio(rng: random.Random) -> tuple[str, object]:
    """A node's radio delay above the floor: a name and a draw (seconds)."""
    kind = rng.choice(("exponential", "gamma", "retries"))
    mean = rng.uniform(0.2e-3, 1.5e-3)
    if kind == "exponential":
        return kind, lambda r: r.expovariate(1 / mean)
    if kind == "gamma":
        # (shape at most 2.5: with more, no packet of a minute comes within 0.1 ms of
        # the floor, and that node's floor is another radio's, unseen by any host)
        shape = rng.uniform(1.0, 2.5)
        return kind, lambda r: r.gammavariate(shape, mean / shape)
    retry, share = rng.uniform(3e-3, 12e-3), rng.uniform(0.02, 0.15)
    return kind, lambda r: r.expovariate(1 / mean) + (retry if r.random() < share else 0.0)


def fifo_packets(seed: int, seconds: float) -> Model:
    """A FIFO UART at 115200 baud fed by 2 to 4 nodes (60 to 95% of the line)."""
    rng = random.Random(f"fifo-{seed}")
    count = rng.randint(2, 4)
    load = rng.uniform(0.60, 0.95)
    names = [rng.choice(STREAMS) for _ in range(count)]
    sizes = [BY_NAME[name].reply_size + REPLY_OVERHEAD for name in names]
    same = rng.random() < 0.5  # one rate for every node, as a deployment usually has
    shares = [1.0] * count if same else [rng.uniform(0.5, 2.0) for _ in range(count)]
    scale = load / sum(s * size * BYTE_TIME for s, size in zip(shares, sizes, strict=True))
    dividers = [max(170, round(CLOCK_HZ / (s * scale))) for s in shares]
    floor = rng.uniform(2e-3, 5e-3)
    quantum = rng.choice((0.0, 0.125e-3, 1e-3))  # when the host's reads wake
    stall_rate, stall_long = rng.uniform(0.05, 1.0), rng.uniform(0.02, 0.3)
    ready: list[tuple[float, int, int, int, float, int]] = []
    periods: dict[int, float] = {}
    kinds = []
    reboot_node = rng.randrange(count) if rng.random() < 0.5 else None
    for i in range(count):
        address = 100 + i
        ppm = rng.uniform(-50, 50)
        rate = 1 + ppm * 1e-6  # device seconds a true second
        step = dividers[i] * TICKS_PER_CLOCK
        periods[address] = sample_period(dividers[i])
        kind, delay = _radio(rng)
        kinds.append(kind)
        radio = random.Random(rng.random())
        powered = [(rng.uniform(0, 1.0), rng.randrange(TIMER_MODULUS) if rng.random() < 0.5
                    else TIMER_MODULUS - rng.randrange(int(seconds * TICKS_PER_SECOND)))]
        if i == reboot_node:
            off = rng.uniform(0.3, 0.6) * seconds
            powered.append((off + rng.uniform(0.5, 3.0), rng.randrange(TICKS_PER_SECOND)))
        for segment, (on, timer0) in enumerate(powered):
            until = powered[segment + 1][0] - 0.5 if segment + 1 < len(powered) else seconds
            at = on + rng.uniform(0, periods[address])  # its first cycle's end
            k, last = 0, 0.0
            while (taken := at + k * step / TICKS_PER_SECOND / rate) < until:
                last = max(taken + floor + delay(radio), last)  # in order over the air
                ready.append((last, address, (timer0 + k * step) % TIMER_MODULUS,
                              sizes[i], taken + floor, segment))
                k += 1
            if segment:  # its discovery packet goes first
                ready.append((on + floor, address, -1, 17, on, segment))
    ready.sort()
    stalls, t = [], rng.expovariate(stall_rate)
    while t < seconds + 1:
        stalls.append((t, t + stall_long * rng.uniform(0.3, 1.0)))
        t += rng.expovariate(stall_rate)
    packets, free, s = [], 0.0, 0
    for at, address, timer, size, truth, segment in ready:
        end = max(at, free) + size * BYTE_TIME
        free = end
        read = math.ceil(end / quantum) * quantum if quantum else end
        while s < len(stalls) and stalls[s][1] <= read:
            s += 1
        if s < len(stalls) and stalls[s][0] <= read:
            read = stalls[s][1]
        packets.append(Packet(read, address, None if timer < 0 else timer, size, truth,
                              segment))
    packets.sort(key=lambda p: p.read)  # (stable: a read's packets keep the line's order)
    about = (f"FIFO, {count} nodes ({'one rate' if same else 'rates apart'}), {load:.0%}"
             f" of the line, radio {'/'.join(kinds)}, reads every {quantum * 1e3:g} ms, "
             f"{len(stalls)} stalls{', a reboot' if reboot_node is not None else ''}")
    return Model(packets, periods, load, about)


# -- what no host can tell apart ----------------------------------------------------------------


def behind(shift: float, seconds: float = 90.0, divider: int = 512) -> Model:
    """Two nodes at one rate on exact crystals, with no radio noise: node 101's samples
    taken ``shift`` seconds after node 100's. While ``shift`` is under 100's packet's
    time on the line, each of 101's packets reaches the base station while one of 100's
    is on the line and begins as it ends: the host reads the same bytes at the same
    instants whatever ``shift`` is, and only the truth differs. Whatever an estimate
    makes of those reads, it gives both runs the same ``time`` s, so node 101's error
    differs by the shifts' difference between them (issue 32: why no estimate can hold
    a target on a run where a node's floor never shows)."""
    period = sample_period(divider)
    floor = 3e-3  # the radio's, the same for both nodes
    size = BY_NAME["accel_angrate"].reply_size + REPLY_OVERHEAD
    step = divider * TICKS_PER_CLOCK
    packets: list[Packet] = []
    free = 0.0
    for k in range(round(seconds / period)):
        taken = 1.0 + k * period
        for node, at in ((100, taken), (101, taken + shift)):
            end = max(at + floor, free) + size * BYTE_TIME
            free = end
            packets.append(Packet(end, node, (7 * node + k * step) % TIMER_MODULUS, size,
                                  at + floor, 0))
    load = 2 * size * BYTE_TIME / period
    return Model(packets, {100: period, 101: period}, load,
                 f"node 101 {shift * 1e3:g} ms behind node 100, {load:.0%} of the line")


MODELS = {"gx2sim": gx2sim_run, "fifo": fifo_packets}


def run(model: str, seed: int, seconds: float) -> Figures:
    return measure(feed(MODELS[model](seed, seconds)))


def runs(model: str, seeds: Iterable[int], seconds: float) -> list[Figures]:
    return [run(model, seed, seconds) for seed in seeds]


def update_cost(streams: dict[tuple[int, int], list[tuple[float, float]]],
                rounds: int = 5) -> float:
    """Microseconds a record that ``NodeClock.update`` takes over each stream's
    (device, arrival) pairs, a fresh clock a stream, best of ``rounds``."""
    count = sum(len(pairs) for pairs in streams.values())
    best = float("inf")
    for _ in range(rounds):
        clocks = {key: NodeClock() for key in streams}
        t0 = time.perf_counter()
        for key, pairs in streams.items():
            update = clocks[key].update
            for device, host in pairs:
                update(device, host)
        best = min(best, time.perf_counter() - t0)
    return best / count * 1e6
