"""A base station over capacity, and host stalls, in simulated time: what the line's
judge (gateway.daemon.station.lineload) is held to, in the suite
(tests/daemon/station/test_line_queue.py) and by hand:

    python bench/linequeue.py
    python bench/linequeue.py --sweep 60   # the sweep's lines: never over capacity

:func:`fifo_queue` is a base station written here from the line's description alone,
apart from gx2-sim: its nodes' packets queue in the order they reach it and leave at
115200 baud, each followed by a gap (``throughput`` below 1: a base station or USB
adapter that leaves the line idle between packets, so that a saturated line reads
under its baud rate), in a buffer of ``buffer`` bytes (None: unbounded) that drops what
does not fit. The host reads at its USB frames and stalls now and then (``stalls``:
(start, seconds), every read meanwhile made at the stall's end).

:func:`judged` plays a model through the gateway's path for the line: each packet's
arrival and device time as gateway.daemon.station.nodes.Node.tally takes them (its
lag, the node's clock fed), the line judged once a second of reads, and the nodes'
clocks held and released as gateway.daemon.station.station.Station does.
"""

from __future__ import annotations

import math
import random
import sys
from dataclasses import dataclass, field

from linemodels import BYTE_TIME, MODELS, Model, Packet

from aspp.clock import FLOOR_NOISE, NodeClock
from aspp.frame import REPLY_OVERHEAD
from aspp.records import BY_NAME
from aspp.timing import (
    TICKS_PER_CLOCK,
    TICKS_PER_SECOND,
    TIMER_MODULUS,
    TimerUnwrapper,
    sample_period,
)
from gateway.daemon.station.lineload import LineLoad, Waited

CAPACITY = 1 / BYTE_TIME
"""Bytes a second of a 115200-baud line."""


@dataclass(frozen=True)
class Stream:
    """One node's stream: its address, record, divider and the seconds it runs."""

    address: int
    record: str = "accel_angrate"
    divider: int = 512
    start: float = 0.0
    stop: float = math.inf


def fifo_queue(seed: int, seconds: float, streams: list[Stream], *,
               throughput: float = 1.0, buffer: int | None = 4096,
               stalls: list[tuple[float, float]] = (),  # type: ignore[assignment]
               floor: float = 3e-3) -> Model:
    """The model of the module's docstring: ``streams`` through a FIFO base station."""
    rng = random.Random(f"queue-{seed}")
    ready = []
    periods = {}
    for stream in streams:
        size = BY_NAME[stream.record].reply_size + REPLY_OVERHEAD
        rate = 1 + rng.uniform(-50, 50) * 1e-6
        period = sample_period(stream.divider)
        periods[stream.address] = period
        radio = random.Random(rng.random())
        step = stream.divider * TICKS_PER_CLOCK
        on = stream.start + rng.uniform(0, period)
        last, k = 0.0, 0
        while (taken := on + k * step / TICKS_PER_SECOND / rate) < min(stream.stop, seconds):
            if taken >= stream.start:
                last = max(taken + floor + radio.expovariate(1 / 0.5e-3), last)
                ticks = (10 * TICKS_PER_SECOND + k * step) % TIMER_MODULUS
                ready.append((last, stream.address, ticks, size, taken + floor))
            k += 1
    ready.sort()
    packets: list[Packet] = []
    queue_end = 0.0  # when the line is free of what the base station holds
    leaving: list[tuple[float, int]] = []  # (instant each queued packet leaves, size)
    quantum = 1e-3
    for at, address, ticks, size, truth in ready:
        while leaving and leaving[0][0] <= at:
            leaving.pop(0)
        if buffer is not None and sum(s for _, s in leaving) + size > buffer:
            continue  # the buffer is full: dropped
        end = max(at, queue_end) + size * BYTE_TIME
        queue_end = end + size * BYTE_TIME * (1 / throughput - 1)  # (its gap after it)
        leaving.append((end, size))
        read = math.ceil(end / quantum) * quantum
        for start, length in stalls:
            if start <= read < start + length:
                read = start + length
        packets.append(Packet(read, address, ticks, size, truth, 0))
    packets.sort(key=lambda p: p.read)
    offered = sum((BY_NAME[s.record].reply_size + REPLY_OVERHEAD) / sample_period(s.divider)
                  for s in streams) / CAPACITY
    return Model(packets, periods, offered,
                 f"FIFO queue, {offered:.0%} of the line offered at most, "
                 f"{throughput:.0%} throughput, {len(stalls)} stalls")


@dataclass
class Judged:
    """A model played through the line's judge: at the first read of each second and
    where it changed, whether the line was over capacity, and each record's error of
    ``time`` against its true instant."""

    bins: list[tuple[float, bool]] = field(default_factory=list)
    errors: dict[int, list[tuple[float, float]]] = field(default_factory=dict)

    def over(self, start: float = -math.inf, stop: float = math.inf) -> list[bool]:
        return [over for at, over in self.bins if start <= at < stop]

    def first_over(self, after: float = -math.inf) -> float | None:
        return next((at for at, over in self.bins if over and at >= after), None)

    def first_room(self, after: float) -> float | None:
        return next((at for at, over in self.bins if not over and at >= after), None)


def judged(model: Model) -> Judged:
    """The model's packets through the gateway's path for the line (module docstring):
    each read's bins closed first, then its packets tallied as Node.tally does."""
    clocks = {node: NodeClock() for node in model.periods}
    unwrappers = {node: TimerUnwrapper(expect=clocks[node].device_at) for node in clocks}
    least: dict[int, float] = {}
    epochs = dict.fromkeys(clocks, 0)

    def waits() -> list[Waited]:
        taken = [Waited(node, least.pop(node, math.inf), epochs[node], clock.floor_seen,
                        clock.held_error() or 0.0) for node, clock in clocks.items()]
        least.clear()
        return taken
    line = LineLoad(CAPACITY, waits)
    out = Judged()
    read_bytes, second, line_free = 0, None, -math.inf
    for packet in model.packets:
        changed = line.read(packet.read, read_bytes, 1.0)
        if changed:
            for clock in clocks.values():
                line.tell(clock)
        if changed or math.floor(packet.read) != second:  # (a read a second, and changes)
            second = math.floor(packet.read)
            out.bins.append((packet.read, line.over))
        read_bytes += packet.size
        node, clock = packet.node, clocks[packet.node]
        if packet.ticks is None:  # a discovery packet: the node powered up
            line_free = packet.read
            clock.reset()
            unwrappers[node].expect_reset()
            continue
        arrival = packet.read - packet.size * BYTE_TIME
        behind, line_free = arrival - line_free < FLOOR_NOISE, packet.read
        device = unwrappers[node].update(packet.ticks, arrival)
        if unwrappers[node].last_was_reset:
            clock.reset()
            epochs[node] += 1
            least.pop(node, None)
        time = clock.update(device, arrival, behind)
        least[node] = min(least.get(node, math.inf), clock.last_wait)
        out.errors.setdefault(node, []).append((packet.truth, time - packet.truth))
    return out


def sweep(seeds: int, seconds: float = 120.0) -> list[str]:
    """The sample-time sweep's lines (bench/linemodels.py, both models, seeds 1 to
    ``seeds``) through the judge: the runs said over capacity at any second (none of
    them is: each is 60 to 95% of the line, stalls included)."""
    said = []
    for model in ("gx2sim", "fifo"):
        for seed in range(1, seeds + 1):
            run = judged(MODELS[model](seed, seconds))
            if any(run.over()):
                said.append(f"{model} seed {seed}: over capacity from {run.first_over()} s")
    return said


def main() -> int:
    if len(sys.argv) > 2 and sys.argv[1] == "--sweep":
        said = sweep(int(sys.argv[2]))
        print(f"the sweep's lines, seeds 1 to {sys.argv[2]} of each model: "
              f"{len(said)} said over capacity" + "".join(f"\n  {s}" for s in said))
        return 1 if said else 0
    streams = [Stream(76), Stream(77), Stream(78, "accel_angrate_orientation", start=20,
                                              stop=60)]
    for throughput, buffer in ((1.0, 4096), (0.906, 4096), (0.906, None)):
        model = fifo_queue(1, 150, streams, throughput=throughput, buffer=buffer)
        run = judged(model)
        print(f"{model.about}, buffer {buffer}: over from {run.first_over()} s, "
              f"room at {run.first_room(60)} s")
    model = fifo_queue(2, 120, [*streams[:2], Stream(78, divider=640)],
                       stalls=[(30.0, 2.0), (60.0, 3.0), (90.0, 0.6)])
    run = judged(model)
    print(f"{model.about}: over at any bin: {any(run.over())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
